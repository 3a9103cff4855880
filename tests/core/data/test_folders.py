"""Folder data sets (one folder per traversal, ground truth from a file) and Dataset.from_arrays."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from vprsnn_export.cli import main
from vprsnn_export.config import Config
from vprsnn_export.data.dataset import Dataset, load_dataset, scoring_truth
from vprsnn_export.data.synthetic import synthetic_route
from vprsnn_export.errors import DataError, InvalidValueError
from vprsnn_export.io.checkpoint import save_checkpoint
from vprsnn_export.trainer.pipeline import train_and_calibrate


def shared_data(name: str) -> Path:
    """``shared/data/<name>`` beside the repository or beside one of its parents (a worktree sits deeper)."""
    for folder in Path(__file__).resolve().parents[3].parents:
        if (folder / "shared/data" / name).is_dir():
            return folder / "shared/data" / name
    return Path(__file__).resolve().parents[4] / "shared/data" / name


LENS = shared_data("lens_example_davis128")
CFG = Config().preprocess


def write_route(folder: Path, n: int = 12, names=("summer", "winter")) -> dict[str, np.ndarray]:
    route = synthetic_route(n, names)
    for name in names:
        (folder / name).mkdir(parents=True)
        for index, image in enumerate(route[name]):  # natural order: 2 before 10
            cv2.imwrite(str(folder / name / f"img{index}.png"), image)
    return route


def test_a_folder_of_traversal_folders_loads_like_the_arrays(tmp_path):
    route = write_route(tmp_path)
    data = load_dataset(tmp_path, ["summer", "winter"], CFG)
    same = Dataset.from_arrays(route, CFG)
    assert data.place_ids.tolist() == list(range(12)) and data.ground_truth == ()
    for name in ("summer", "winter"):
        np.testing.assert_array_equal(data.traversal(name), same.traversal(name))
    picked = load_dataset(tmp_path, ["winter"], CFG, places="3:4")
    np.testing.assert_array_equal(picked.traversal("winter"), same.traversal("winter")[3:7])


@pytest.mark.parametrize("form", ["matrix", "lists", "csv"])
def test_ground_truth_files_become_the_scoring_truth(tmp_path, form):
    write_route(tmp_path)
    truth = np.eye(12, dtype=np.int64)
    truth[4, 4] = 0
    truth[6, 4] = truth[4, 6] = 1  # query 4 matches reference 6 only (symmetric: a square matrix must be)
    if form == "matrix":
        np.save(tmp_path / "summer_winter_GT.npy", truth)
    elif form == "lists":
        lists = np.empty(12, dtype=object)
        lists[:] = [list(np.flatnonzero(truth[:, q])) for q in range(12)]
        np.save(tmp_path / "summer_winter_GT.npy", lists, allow_pickle=True)
    else:
        pairs = "\n".join(f"{q},{r}" for r, q in zip(*np.nonzero(truth), strict=True))
        (tmp_path / "summer_winter_GT.csv").write_text("query,reference\n" + pairs + "\n")
    data = load_dataset(tmp_path, ["summer", "winter"], CFG)
    assert [(t.reference, t.query) for t in data.ground_truth] == [("summer", "winter"), ("winter", "summer")]
    alone = load_dataset(tmp_path, ["winter"], CFG, places="2:6")  # the query traversal alone, as evaluate loads it
    scored = scoring_truth(alone, ["summer"], "winter")
    np.testing.assert_array_equal(scored.matrix, truth > 0)
    assert scored.source.endswith(f"summer_winter_GT.{'csv' if form == 'csv' else 'npy'}")
    assert scoring_truth(alone, ["winter"], "winter") is None  # a reference traversal is its own truth


def test_folder_defects_are_one_clear_error(tmp_path):
    write_route(tmp_path)
    with pytest.raises(DataError, match="traversals are: summer, winter"):
        load_dataset(tmp_path, ["autumn"], CFG)
    np.save(tmp_path / "summer_winter_GT.npy", np.zeros((12, 12), dtype=np.int64))
    with pytest.raises(DataError, match="12 queries have no matching reference"):
        load_dataset(tmp_path, ["summer", "winter"], CFG)
    np.save(tmp_path / "summer_winter_GT.npy", np.zeros((3, 3)))
    with pytest.raises(DataError, match="shape"):
        load_dataset(tmp_path, ["summer", "winter"], CFG)
    (tmp_path / "summer_winter_GT.npy").unlink()
    (tmp_path / "winter" / "img11.png").unlink()
    with pytest.raises(DataError, match="different numbers of frames"):
        load_dataset(tmp_path, ["summer", "winter"], CFG)
    with pytest.raises(InvalidValueError, match="distinct"):
        Dataset.from_arrays({"a": np.zeros((2, 8, 8), np.uint8)}, CFG, place_ids=[1, 1])


def test_without_a_file_traversals_of_different_lengths_are_not_scored_by_index(tmp_path):
    write_route(tmp_path)
    (tmp_path / "winter" / "img11.png").unlink()
    alone = load_dataset(tmp_path, ["winter"], CFG)
    with pytest.raises(DataError, match="not index-aligned and no ground-truth file"):
        scoring_truth(alone, ["summer"], "winter")
    with pytest.raises(DataError, match="reference traversal 'autumn' is not a folder here"):
        scoring_truth(alone, ["autumn"], "winter")


@pytest.mark.skipif(not LENS.is_dir(), reason=f"the shared LENS example is absent ({LENS})")
def test_the_lens_folder_evaluates_with_its_npy_ground_truth(tmp_path, capsys):
    cfg = Config().replace(**{"encoder.timesteps": 40, "train.epochs": 1, "network.n_neurons": 32})
    data = load_dataset(LENS, ["example-reference"], cfg.preprocess, places="0:30")
    trained = train_and_calibrate(data, ["example-reference"], cfg, progress=False, selection={"places": "0:30"})
    ckpt = save_checkpoint(tmp_path / "lens.npz", trained)
    argv = ["evaluate", str(ckpt), "--query", "example-query", "--k", "1,3", "--json", "--quiet"]
    assert main([*argv, "--match-window", "1"]) == 2  # the file decides: a window is for index-aligned data
    assert "example-reference_example-query_GT.npy says which reference frames match" in capsys.readouterr().err
    assert main(argv) == 0
    rows = json.loads(capsys.readouterr().out)["results"]
    assert [(r["strategy"], r["k"], r["n_queries"]) for r in rows][-1] == ("wprob", 3, 30)
    assert all(0 <= r["accuracy"] <= 1 for r in rows)
    assert main(["evaluate", str(ckpt), "--data", str(LENS), "--query", "night", "--quiet"]) == 2
    assert "its traversals are: example-query, example-reference" in capsys.readouterr().err
