"""Images are decoded from bytes Python read: any path Python opens works, a bad image is one error, no decoder noise."""

from __future__ import annotations

import os
import random
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from vprsnn_export.data.preprocess import read_grey_image
from vprsnn_export.data.synthetic import synthetic_route
from vprsnn_export.errors import DataError

IMAGE = cv2.GaussianBlur(np.random.default_rng(0).integers(0, 256, (120, 160), dtype=np.uint8), (0, 0), 3)
PNG = cv2.imencode(".png", IMAGE)[1].tobytes()
JPEG = cv2.imencode(".jpg", IMAGE)[1].tobytes()


def non_utf8_folder(parent: Path) -> bytes:
    """``parent/route<0xff>`` as a bytes path, made; the test is skipped where the file system refuses the name."""
    folder = os.path.join(os.fsencode(parent), b"route\xff")
    try:
        os.mkdir(folder)
    except OSError as exc:
        pytest.skip(f"this file system refuses a name that is not UTF-8 ({exc})")
    return folder


def test_a_folder_name_that_is_not_utf8_decodes(tmp_path: Path) -> None:
    folder = non_utf8_folder(tmp_path)
    for name, data in (("a.png", PNG), ("a.jpg", JPEG)):
        path = os.path.join(folder, name.encode())
        with open(path, "wb") as file:
            file.write(data)
        grey = read_grey_image(Path(os.fsdecode(path)))
        np.testing.assert_array_equal(grey, cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE))
    np.testing.assert_array_equal(read_grey_image(Path(os.fsdecode(folder)) / "a.png"), IMAGE)


@pytest.mark.parametrize(
    ("name", "data", "problem"),
    [
        ("half.png", PNG[: len(PNG) // 2], "unreadable or corrupt image"),
        ("tail.png", PNG[:-1], "unreadable or corrupt image"),
        ("half.jpg", JPEG[: len(JPEG) // 2], "unreadable or corrupt image"),
        ("half_with_end.jpg", JPEG[: len(JPEG) // 2] + b"\xff\xd9", "truncated or corrupt image"),
        ("garbage.png", b"\x89PNG\r\n\x1a\n this is not an image", "unreadable or corrupt image"),
        ("garbage.jpg", random.Random(0).randbytes(64), "unreadable or corrupt image"),
        ("empty.png", b"", "empty image file"),
    ],
)
def test_a_bad_image_is_one_error_and_the_decoder_prints_nothing(tmp_path, capfd, name, data, problem) -> None:
    (tmp_path / name).write_bytes(data)
    with pytest.raises(DataError, match=problem) as info:
        read_grey_image(tmp_path / name, context="frame 3")
    assert info.value.path == tmp_path / name and str(info.value).endswith("(frame 3)")
    assert capfd.readouterr() == ("", "")  # libpng's and libjpeg's lines are quoted in the error, not printed


def test_a_truncated_jpeg_is_not_accepted_partly_decoded(tmp_path) -> None:
    (tmp_path / "cut.jpg").write_bytes(JPEG[: len(JPEG) // 2] + b"\xff\xd9")
    assert cv2.imdecode(np.frombuffer((tmp_path / "cut.jpg").read_bytes(), np.uint8), 0) is not None  # OpenCV would
    with pytest.raises(DataError, match="premature end"):
        read_grey_image(tmp_path / "cut.jpg")


def test_evaluate_on_a_non_utf8_folder_with_a_truncated_image_is_one_line_and_exit_2(
    tmp_path, capsys, cli_checkpoint
) -> None:
    ckpt = cli_checkpoint("synthetic:8", "--quiet", "--timesteps", "20", "--epochs", "1", "--threads", "1")
    capsys.readouterr()
    folder = non_utf8_folder(tmp_path)
    for name, images in synthetic_route(8, ("summer", "winter")).items():
        os.mkdir(os.path.join(folder, name.encode()))
        for index, image in enumerate(images):
            data = cv2.imencode(".png", image)[1].tobytes()
            cut = name == "winter" and index == 3
            with open(os.path.join(folder, name.encode(), b"img%d.png" % index), "wb") as file:
                file.write(data[: len(data) // 2] if cut else data)
    command = [sys.executable, "-m", "vprsnn_export", "evaluate", os.fsencode(ckpt), "--data", folder]
    done = subprocess.run(
        [*command, b"--query", b"winter", b"--quiet", b"--threads", b"1"],
        capture_output=True,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
        timeout=300,
    )
    err = done.stderr.decode(errors="replace")
    assert done.returncode == 2, err  # it was a segfault (139) inside cv2.imread
    assert err.count("\n") == 1 and err.startswith("error: ") and "Traceback" not in err
    assert "img3.png" in err and "unreadable or corrupt image" in err and "frame 3 of traversal 'winter'" in err
