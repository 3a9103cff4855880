"""Place manifests, selection (--places, --subset), synthetic data and every expected load error."""

from __future__ import annotations

import hashlib
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from vprsnn_export.config import preset
from vprsnn_export.data.dataset import Dataset, load_dataset, parse_places
from vprsnn_export.data.preprocess import preprocess_images
from vprsnn_export.data.synthetic import synthetic_fingerprint, synthetic_route
from vprsnn_export.errors import DataError, InvalidValueError

CFG = preset("paper").preprocess  # the patch-normalised intensity channel these tests pin
NORDLAND = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "nordland_64x32_summer_winter"
TRAVERSALS = ("summer", "winter")
N_PLACES = 8


def _write_csv(path: Path, header: list[str], rows: list[list[object]]) -> Path:
    lines = [",".join(header)] + [",".join(str(cell) for cell in row) for row in rows]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


@pytest.fixture()
def data_dir(tmp_path: Path) -> Path:
    """Tiny manifest: 8 places (ids 10..17), two traversals of random 16x32 PNGs, plus an extra column."""
    folder = tmp_path / "route"
    rng = np.random.default_rng(0)
    rows = []
    for place in range(10, 10 + N_PLACES):
        row: list[object] = [place]
        for name in TRAVERSALS:
            (folder / name).mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(folder / name / f"{place}.png"), rng.integers(0, 256, (16, 32), dtype=np.uint8))
            row.append(f"{name}/{place}.png")
        rows.append(row + [0])
    _write_csv(folder / "places.csv", ["place_id", *TRAVERSALS, "flag"], rows)
    return folder


def _expected(folder: Path, name: str, ids: list[int]) -> np.ndarray:
    grey = np.stack([cv2.imread(str(folder / name / f"{place}.png"), cv2.IMREAD_GRAYSCALE) for place in ids])
    return preprocess_images(grey, CFG)


def _error(kind: type, *args: object, **kwargs: object) -> str:
    with pytest.raises(kind) as info:
        load_dataset(*args, **kwargs)  # type: ignore[arg-type]
    return str(info.value)


# --- loading and selection -------------------------------------------------------------------


def test_load_whole_manifest(data_dir: Path) -> None:
    data = load_dataset(data_dir / "places.csv", TRAVERSALS, CFG)
    assert isinstance(data, Dataset)
    assert data.place_ids.dtype == np.int64 and data.place_ids.tolist() == list(range(10, 18))
    assert data.source == str(data_dir / "places.csv")
    assert data.manifest_sha256 == hashlib.sha256((data_dir / "places.csv").read_bytes()).hexdigest()
    assert data.traversals == TRAVERSALS and data.n_places == N_PLACES
    for name in TRAVERSALS:
        assert data.traversal(name).dtype == np.float32 and data.traversal(name).shape == (N_PLACES, 784)
        assert np.array_equal(data.traversal(name), _expected(data_dir, name, list(range(10, 18))))


def test_folder_means_its_places_csv(data_dir: Path) -> None:
    data = load_dataset(data_dir, ["winter"], CFG)
    assert data.traversals == ("winter",) and data.place_ids.tolist() == list(range(10, 18))


def test_manifest_order_is_kept(data_dir: Path) -> None:
    _write_csv(
        data_dir / "shuffled.csv",
        ["place_id", "summer"],
        [[13, "summer/13.png"], [11, "summer/11.png"], [12, "summer/12.png"]],
    )
    data = load_dataset(data_dir / "shuffled.csv", ["summer"], CFG)
    assert data.place_ids.tolist() == [13, 11, 12]
    assert np.array_equal(data.traversal("summer"), _expected(data_dir, "summer", [13, 11, 12]))


def test_places_selection_order(data_dir: Path) -> None:
    data = load_dataset(data_dir, TRAVERSALS, CFG, places="11:3:2")
    assert data.place_ids.tolist() == [11, 13, 15]
    assert np.array_equal(data.traversal("winter"), _expected(data_dir, "winter", [11, 13, 15]))


def test_subset_selection_order(data_dir: Path, tmp_path: Path) -> None:
    subset = _write_csv(tmp_path / "subset.csv", ["subset_id", "place_id"], [[0, 16], [1, 10], [2, 13]])
    data = load_dataset(data_dir, TRAVERSALS, CFG, subset=subset)
    assert data.place_ids.tolist() == [16, 10, 13]
    for name in TRAVERSALS:
        assert np.array_equal(data.traversal(name), _expected(data_dir, name, [16, 10, 13]))


def test_progress_bar_goes_to_stderr(data_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    load_dataset(data_dir, TRAVERSALS, CFG, places="10:2", progress=True)
    captured = capsys.readouterr()
    assert captured.out == "" and "4/4" in captured.err


def test_patch_norm_off(data_dir: Path) -> None:
    data = load_dataset(data_dir, ["summer"], replace(CFG, patch_norm=False), places="10:1")
    grey = cv2.imread(str(data_dir / "summer" / "10.png"), cv2.IMREAD_GRAYSCALE)
    assert np.array_equal(
        data.traversal("summer")[0], cv2.resize(grey, (28, 28), interpolation=cv2.INTER_AREA).ravel() / np.float32(255)
    )


@pytest.mark.parametrize(("spec", "expected"), [("0:5", (0, 5, 1)), ("3:4:10", (3, 4, 10)), (" 7:1 ", (7, 1, 1))])
def test_parse_places(spec: str, expected: tuple[int, int, int]) -> None:
    assert parse_places(spec) == expected


@pytest.mark.parametrize("spec", ["", "5", "a:b", "1:0", "-1:3", "1:2:0", "1:2:-1", "1:2:3:4", "1.5:2"])
def test_parse_places_rejects(spec: str) -> None:
    with pytest.raises(InvalidValueError, match="START:COUNT"):
        parse_places(spec)


# --- synthetic data --------------------------------------------------------------------------


def test_synthetic_default() -> None:
    data = load_dataset("synthetic", TRAVERSALS, CFG)
    route = synthetic_route(60, TRAVERSALS)
    assert data.source == "synthetic" and data.place_ids.tolist() == list(range(60))
    assert data.manifest_sha256 == synthetic_fingerprint(60, ("summer", "winter", "spring", "fall"))
    assert np.array_equal(data.traversal("winter"), preprocess_images(route["winter"], CFG))


def test_synthetic_size_and_selection(tmp_path: Path) -> None:
    route = synthetic_route(30, ("fall",))
    data = load_dataset("synthetic:30", ["fall"], CFG, places="5:3:10")
    assert data.place_ids.tolist() == [5, 15, 25]
    assert np.array_equal(data.traversal("fall"), preprocess_images(route["fall"][[5, 15, 25]], CFG))
    subset = _write_csv(tmp_path / "subset.csv", ["place_id"], [[29], [0]])
    assert load_dataset("synthetic:30", ["fall"], CFG, subset=subset).place_ids.tolist() == [29, 0]
    assert (
        load_dataset("synthetic:30", ["summer"], CFG).manifest_sha256
        == load_dataset("synthetic:30", ["fall"], CFG).manifest_sha256
    )


def test_synthetic_errors() -> None:
    assert "autumn" in _error(DataError, "synthetic", ["summer", "autumn"], CFG)
    assert "summer, winter" in _error(DataError, "synthetic", ["autumn"], CFG)
    assert "synthetic:0" in _error(InvalidValueError, "synthetic:0", TRAVERSALS, CFG)
    assert "synthetic:x" in _error(InvalidValueError, "synthetic:x", TRAVERSALS, CFG)
    assert "ids 0..59" in _error(DataError, "synthetic", TRAVERSALS, CFG, places="58:3")
    # a whole Config where its preprocess settings belong: one error naming the argument, not an AttributeError
    assert "cfg must be a PreprocessConfig, got Config" in _error(
        InvalidValueError, "synthetic", TRAVERSALS, preset("paper")
    )


# --- errors ------------------------------------------------------------------------------------


def test_missing_manifest(tmp_path: Path) -> None:
    message = _error(DataError, tmp_path / "absent.csv", TRAVERSALS, CFG)
    assert "absent.csv" in message and "no such place manifest" in message


def test_missing_nordland_folder_points_to_shared_data(tmp_path: Path) -> None:
    message = _error(DataError, tmp_path / "nordland_64x32_summer_winter", TRAVERSALS, CFG)
    assert "../shared/data" in message


def test_folder_without_places_csv(tmp_path: Path) -> None:
    assert "places.csv" in _error(DataError, tmp_path, TRAVERSALS, CFG)


def test_manifest_without_place_id(tmp_path: Path) -> None:
    manifest = _write_csv(tmp_path / "m.csv", ["id", "summer"], [[0, "a.png"]])
    message = _error(DataError, manifest, ["summer"], CFG)
    assert "m.csv" in message and "'place_id'" in message


def test_empty_manifest(tmp_path: Path) -> None:
    (tmp_path / "empty.csv").write_text("", encoding="utf-8")
    assert "empty.csv" in _error(DataError, tmp_path / "empty.csv", ["summer"], CFG)
    header_only = _write_csv(tmp_path / "header.csv", ["place_id", "summer"], [])
    assert "no places" in _error(DataError, header_only, ["summer"], CFG)


def test_traversal_column_absent(data_dir: Path) -> None:
    message = _error(DataError, data_dir, ["summer", "autumn"], CFG)
    assert "'autumn'" in message and "place_id, summer, winter, flag" in message and "places.csv" in message


def test_bad_traversal_names(data_dir: Path) -> None:
    assert "place_id" in _error(InvalidValueError, data_dir, ["place_id", "summer"], CFG)
    assert "traversal" in _error(InvalidValueError, data_dir, [], CFG)
    assert load_dataset(data_dir, ["summer", "summer"], CFG).traversals == ("summer",)


def test_duplicate_place_id(data_dir: Path) -> None:
    manifest = _write_csv(
        data_dir / "dup.csv",
        ["place_id", "summer"],
        [[10, "summer/10.png"], [11, "summer/11.png"], [10, "summer/12.png"]],
    )
    message = _error(DataError, manifest, ["summer"], CFG)
    assert "dup.csv" in message and "duplicate place_id 10" in message and "lines 2 and 4" in message


@pytest.mark.parametrize("value", ["x7", "1.5", ""])
def test_non_integer_place_id(data_dir: Path, value: str) -> None:
    manifest = _write_csv(
        data_dir / "bad.csv", ["place_id", "summer"], [[10, "summer/10.png"], [value, "summer/11.png"]]
    )
    message = _error(DataError, manifest, ["summer"], CFG)
    assert "bad.csv" in message and "line 3" in message and "not an integer" in message


def test_selected_place_not_in_manifest(data_dir: Path, tmp_path: Path) -> None:
    message = _error(DataError, data_dir, TRAVERSALS, CFG, places="16:4")
    assert "places.csv" in message and "18, 19" in message and "ids 10..17" in message
    subset = _write_csv(tmp_path / "s.csv", ["place_id"], [[12], [99]])
    message = _error(DataError, data_dir, TRAVERSALS, CFG, subset=subset)
    assert "99" in message and "s.csv" in message


def test_subset_errors(data_dir: Path, tmp_path: Path) -> None:
    assert "nope.csv" in _error(DataError, data_dir, TRAVERSALS, CFG, subset=tmp_path / "nope.csv")
    no_column = _write_csv(tmp_path / "nocol.csv", ["id"], [[10]])
    assert "nocol.csv" in _error(DataError, data_dir, TRAVERSALS, CFG, subset=no_column)
    empty = _write_csv(tmp_path / "empty.csv", ["place_id"], [])
    message = _error(DataError, data_dir, TRAVERSALS, CFG, subset=empty)
    assert "empty selection" in message and "empty.csv" in message
    dup = _write_csv(tmp_path / "dup.csv", ["place_id"], [[10], [10]])
    assert "duplicate place_id 10" in _error(DataError, data_dir, TRAVERSALS, CFG, subset=dup)
    bad = _write_csv(tmp_path / "bad.csv", ["place_id"], [["ten"]])
    assert "not an integer" in _error(DataError, data_dir, TRAVERSALS, CFG, subset=bad)


def test_subset_and_places_together(data_dir: Path, tmp_path: Path) -> None:
    subset = _write_csv(tmp_path / "s.csv", ["place_id"], [[12]])
    assert "--subset" in _error(InvalidValueError, data_dir, TRAVERSALS, CFG, subset=subset, places="10:2")


def test_missing_image(data_dir: Path) -> None:
    (data_dir / "winter" / "14.png").unlink()
    message = _error(DataError, data_dir, TRAVERSALS, CFG)
    assert str(data_dir / "winter" / "14.png") in message and "not found" in message and "place_id 14" in message
    assert load_dataset(data_dir, TRAVERSALS, CFG, places="10:4").n_places == 4


def test_corrupt_image(data_dir: Path) -> None:
    (data_dir / "summer" / "12.png").write_bytes(b"not a png at all")
    message = _error(DataError, data_dir, ["summer"], CFG)
    assert str(data_dir / "summer" / "12.png") in message and "corrupt" in message


def test_empty_traversal_cell(data_dir: Path) -> None:
    manifest = _write_csv(
        data_dir / "holes.csv",
        ["place_id", "summer", "winter"],
        [[10, "summer/10.png", "winter/10.png"], [11, "summer/11.png", ""]],
    )
    message = _error(DataError, manifest, TRAVERSALS, CFG)
    assert "holes.csv" in message and "'winter'" in message and "place_id 11" in message
    assert load_dataset(manifest, ["summer"], CFG).n_places == 2


def test_missing_loaded_traversal(data_dir: Path) -> None:
    data = load_dataset(data_dir, ["summer"], CFG)
    with pytest.raises(DataError, match="available: summer"):
        data.traversal("winter")


# --- real data ---------------------------------------------------------------------------------


@pytest.mark.skipif(
    not (NORDLAND / "places.csv").is_file(), reason=f"Nordland data not found at {NORDLAND} (see docs/data.md)"
)
def test_real_nordland_five_places() -> None:
    data = load_dataset(NORDLAND, TRAVERSALS, CFG, places="1000:5")
    assert data.place_ids.tolist() == [1000, 1001, 1002, 1003, 1004]
    assert data.manifest_sha256 == hashlib.sha256((NORDLAND / "places.csv").read_bytes()).hexdigest()
    for name in TRAVERSALS:
        images = data.traversal(name)
        assert images.shape == (5, 784) and images.dtype == np.float32
        assert images.min() == 0.0 and images.max() == 1.0
    assert not np.array_equal(data.traversal("summer"), data.traversal("winter"))
    subset = load_dataset(NORDLAND, ["summer"], CFG, subset=NORDLAND / "subset_100_places.csv")
    assert subset.n_places == 100 and subset.place_ids[:3].tolist() == [17, 36, 56]
