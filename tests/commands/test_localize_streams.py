"""`localize --frames` on streams as robots record them: ROS bags, event recordings; bounded inputs.

A bag and an event file give the same decisions as their frames written as a folder, with a latency per
frame; oversized images and endless stdin lines stop with one line before they take the memory.
"""

from __future__ import annotations

import io
import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from vprsnn_export.cli import main
from vprsnn_export.data.frames import MAX_LINE
from vprsnn_export.data.synthetic import synthetic_route
from vprsnn_export.export.model import save_fixed_point
from vprsnn_export.io.checkpoint import checkpoint_sha256, save_checkpoint
from vprsnn_export.runtime.deployment import deploy

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core" / "data"))
from test_bags import write_bag  # noqa: E402
from test_events import frames_to_events  # noqa: E402

ARGS = ("--k", "3", "--threshold", "0.5", "--quiet")


@pytest.fixture(scope="module")
def model(tmp_path_factory, trained) -> Path:
    """The session's trained network (24 synthetic places, tests/conftest.py) as a 4-bit fixed-point model."""
    ckpt, data = trained
    folder = tmp_path_factory.mktemp("streams")
    net = save_checkpoint(folder / "net.npz", ckpt)
    fixed = deploy(ckpt, checkpoint_sha256(net), 4, reference_images={"summer": data.traversal("summer")})
    return save_fixed_point(folder / "q4.npz", fixed)


def folder_of(frames: np.ndarray, folder: Path) -> Path:
    folder.mkdir()
    for index, image in enumerate(frames):
        cv2.imwrite(str(folder / f"f{index}.png"), image)
    return folder


def localize(capsys, *argv) -> list[dict]:
    assert main(["localize", *map(str, argv), *ARGS]) == 0
    return [json.loads(line) for line in capsys.readouterr().out.splitlines()]


def decisions(lines: list[dict]) -> list[tuple]:
    return [(d["frame"], d["place_id"], d["confidence"], d["accepted"]) for d in lines]


def latencies(lines: list[dict]) -> list[float]:
    return [d["latency_ms"] for d in lines]


@pytest.mark.parametrize("ros1", [False, True], ids=["ros2", "ros1"])
def test_a_bag_decides_like_its_frames_in_a_folder(model, tmp_path, capsys, ros1):
    pytest.importorskip("rosbags")
    winter = synthetic_route(24, ("winter",))["winter"]
    bag = write_bag(tmp_path / ("run.bag" if ros1 else "run"), {"/camera/image": [("mono8", g) for g in winter]}, ros1)
    from_bag = localize(capsys, model, "--frames", bag)
    from_folder = localize(capsys, model, "--frames", folder_of(winter, tmp_path / "winter"))
    assert len(from_bag) == 24 and decisions(from_bag) == decisions(from_folder)
    assert any(d["accepted"] for d in from_bag)  # something is decided, not 24 refusals
    assert [d["name"] for d in from_bag[:2]] == [f"{bag.name}#0", f"{bag.name}#1"]
    assert all(ms > 0 for ms in latencies(from_bag))


def test_a_bag_with_two_image_topics_needs_topic(model, tmp_path, capsys):
    pytest.importorskip("rosbags")
    winter = synthetic_route(4, ("winter",))["winter"]
    bag = write_bag(
        tmp_path / "two", {"/left": [("mono8", g) for g in winter], "/right": [("bgr8", g) for g in winter]}
    )
    assert main(["localize", str(model), "--frames", str(bag), *ARGS]) == 2
    err = capsys.readouterr().err
    assert "image topics /left, /right: give --topic" in err and len(err.strip().splitlines()) == 1
    assert len(localize(capsys, model, "--frames", bag, "--topic", "/right")) == 4


def test_an_event_recording_decides_like_its_binned_frames_in_a_folder(model, tmp_path, capsys):
    counts = synthetic_route(24, ("winter",))["winter"] // 8  # counts of 0..31 events per pixel and frame
    counts[:, 0, 0] = np.maximum(counts[:, 0, 0], 1)  # every window holds an event
    events = frames_to_events(counts, 50_000)
    np.save(tmp_path / "events.npy", events)
    from_events = localize(capsys, model, "--frames", tmp_path / "events.npy", "--event-window-us", "50000")
    from_folder = localize(capsys, model, "--frames", folder_of(counts, tmp_path / "binned"))
    assert len(from_events) == 24 and decisions(from_events) == decisions(from_folder)
    assert len({d["place_id"] for d in from_events}) > 1  # decisions that differ from frame to frame
    assert all(ms > 0 for ms in latencies(from_events))
    per_frame = events.size // 12
    by_count = localize(capsys, model, "--frames", tmp_path / "events.npy", "--event-count", str(per_frame))
    assert len(by_count) == -(-events.size // per_frame)  # the last window may be partial


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (("--event-window-us", "0"), "expected a positive whole number"),
        (("--event-window-us", "1_0"), "expected a positive whole number"),
        (("--event-window-us", "5", "--event-count", "5"), "not allowed with argument"),
        ((), "binned into frames by --event-window-us or --event-count"),
        (("--topic", "/cam"), "--topic is for a ROS bag"),
    ],
)
def test_bad_event_and_topic_options_are_one_line(model, tmp_path, capsys, extra, message):
    np.save(tmp_path / "events.npy", frames_to_events(np.ones((2, 32, 64), np.uint8), 1000))
    assert main(["localize", str(model), "--frames", str(tmp_path / "events.npy"), *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


def test_an_oversized_image_is_refused_before_decoding(model, tmp_path, capsys, monkeypatch):
    """A 20000 x 20000 PNG (a few hundred kB on disk, 400 MB decoded) under --memory-limit 100M: one line, no decode."""
    import vprsnn_export.data.preprocess as preprocess

    frames = tmp_path / "big"
    frames.mkdir()
    row = cv2.imencode(".png", np.zeros((1, 20000), np.uint8))[1].tobytes()
    header = bytearray(row[:33])  # signature + IHDR with the height patched to 20000 (its CRC is not checked first)
    header[20:24] = (20000).to_bytes(4, "big")
    (frames / "f0.png").write_bytes(bytes(header) + row[33:])

    def no_decode(data):
        raise AssertionError("decoded past the memory limit")

    monkeypatch.setattr(preprocess, "decode_grey", no_decode)
    assert main(["localize", str(model), "--frames", str(frames), "--memory-limit", "100M", *ARGS]) == 2
    err = capsys.readouterr().err
    assert "decoded image 20000 x 20000" in err and "over the limit of 100.0 MiB" in err
    assert len(err.strip().splitlines()) == 1


def test_a_stdin_line_is_bounded(model, capsys, monkeypatch):
    monkeypatch.setattr("sys.stdin", io.StringIO("x" * (10 * MAX_LINE)))  # no newline: one endless line
    assert main(["localize", str(model), "--frames", "-", *ARGS]) == 2
    err = capsys.readouterr().err
    assert f"longer than {MAX_LINE} characters" in err and len(err.strip().splitlines()) == 1


def test_a_damaged_video_prints_nothing_above_the_error(model, tmp_path, capfd):
    clip = tmp_path / "broken.avi"
    clip.write_bytes(b"RIFF\x00\x10\x00\x00AVI LIST" + bytes(range(256)) * 8)
    assert main(["localize", str(model), "--frames", str(clip), *ARGS]) == 2
    out, err = capfd.readouterr()
    assert out == "" and len(err.strip().splitlines()) == 1, err


def test_stdin_that_is_not_text_is_one_line(model, capsys, monkeypatch):
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(b"\xff\xfe\x00garbage\n"), encoding="utf-8"))
    assert main(["localize", str(model), "--frames", "-", *ARGS]) == 2
    err = capsys.readouterr().err
    assert "stdin" in err and len(err.strip().splitlines()) == 1


def test_stream_options_are_refused_with_calibrate(model, capsys):
    assert main(["localize", str(model), "--calibrate", "winter", "--topic", "/cam", *ARGS]) == 2
    err = capsys.readouterr().err
    assert "are for --frames, not --calibrate" in err and len(err.strip().splitlines()) == 1


def test_a_cut_video_ends_with_one_error_after_its_good_frames(model, tmp_path, capfd):
    clip = tmp_path / "run.avi"
    writer = cv2.VideoWriter(str(clip), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 32), isColor=True)
    for grey in synthetic_route(20, ("winter",))["winter"]:
        writer.write(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR))
    writer.release()
    assert main(["localize", str(model), "--frames", str(clip), *ARGS]) == 0
    assert len(capfd.readouterr().out.splitlines()) == 20  # the whole video: no error
    data = clip.read_bytes()
    clip.write_bytes(data[: len(data) * 2 // 3])
    assert main(["localize", str(model), "--frames", str(clip), *ARGS]) == 2
    out, err = capfd.readouterr()
    decided = len(out.splitlines())
    assert 0 < decided < 20 and f"ended after {decided} of the 20 frames it declares" in err
    assert len(err.strip().splitlines()) == 1
