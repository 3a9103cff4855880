"""The field's layouts as shipped (issue 31): LENS (`<traversal>/` folders + `<query>_<reference>_GT.npy`,
GT[reference, query], traversals of different lengths with an offset) and VPR-Bench (`ref/`, `query/`,
`ground_truth_new.npy` of [query, reference list] rows) are scored against their ground truth by every
command, with the numbers a hand-made, GT-exact manifest gives on the same spike counts; data that is not
index-aligned and has no ground truth is refused, never scored by index. Data sets made here from the
synthetic route (no third-party images)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from vprsnn_export.cli import main
from vprsnn_export.data.dataset import load_dataset, scoring_truth
from vprsnn_export.data.synthetic import synthetic_route
from vprsnn_export.data.truth import GroundTruth
from vprsnn_export.io.checkpoint import load_checkpoint
from vprsnn_export.readout.scoring import readout_rows
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.evaluation import evaluate_float

N_REFERENCE, N_QUERY, OFFSET = 30, 20, 6  # query j is reference place j + OFFSET
TINY = ["--timesteps", "20", "--epochs", "1", "--neurons", "24", "--quiet"]


def write_traversal(folder: Path, images: np.ndarray) -> None:
    folder.mkdir(parents=True)
    for index, image in enumerate(images):
        cv2.imwrite(str(folder / f"image_{index:04d}.png"), image)


def offset_route(root: Path, reference: str, query: str) -> np.ndarray:
    """``reference`` holds places 0..29, ``query`` places 6..25 seen in winter; returns GT[reference, query]."""
    route = synthetic_route(N_REFERENCE, ("summer", "winter"))
    write_traversal(root / reference, route["summer"])
    write_traversal(root / query, route["winter"][OFFSET : OFFSET + N_QUERY])
    truth = np.zeros((N_REFERENCE, N_QUERY), dtype=np.int64)
    truth[np.arange(N_QUERY) + OFFSET, np.arange(N_QUERY)] = 1
    return truth


def lens_layout(root: Path) -> tuple[str, str]:
    truth = offset_route(root, "sunset1", "sunset2")
    np.save(root / "sunset2_sunset1_GT.npy", truth)  # LENS: <query>_<reference>_GT.npy holding GT[reference, query]
    return "sunset1", "sunset2"


def vpr_bench_layout(root: Path) -> tuple[str, str]:
    truth = offset_route(root, "ref", "query")
    rows = np.empty((N_QUERY, 2), dtype=object)
    rows[:, 0] = np.arange(N_QUERY)
    rows[:, 1] = [np.flatnonzero(truth[:, q]) for q in range(N_QUERY)]
    np.save(root / "ground_truth_new.npy", rows, allow_pickle=True)  # VPR-Bench's own format, pickled
    return "ref", "query"


def dicts(rows: list) -> list[dict]:
    return [row if isinstance(row, dict) else row.to_dict() for row in rows]


def evaluate_json(capsys, *argv: str) -> list[dict]:
    capsys.readouterr()
    assert main(["evaluate", *argv, "--json", "--quiet"]) == 0, capsys.readouterr().err
    return json.loads(capsys.readouterr().out)["results"]


@pytest.mark.parametrize("layout", [lens_layout, vpr_bench_layout], ids=["lens", "vpr-bench"])
def test_a_layout_as_shipped_scores_like_a_gt_exact_manifest(tmp_path, capsys, layout):
    data = tmp_path / "data"
    reference, query = layout(data)
    ckpt_path = tmp_path / "net.npz"
    train = ["train", "--data", str(data), "--reference", reference, *TINY, "--out", str(ckpt_path)]
    assert main(train) == 0
    rows = evaluate_json(capsys, str(ckpt_path), "--query", query, "--k", "1,3")
    assert [(r["strategy"], r["k"], r["n_queries"]) for r in rows][-1] == ("wprob", 3, N_QUERY)

    ckpt = load_checkpoint(ckpt_path)
    dataset = load_dataset(data, [query], ckpt.config.preprocess)
    truth = scoring_truth(dataset, [reference], query)
    assert isinstance(truth, GroundTruth) and truth.matrix.shape == (N_REFERENCE, N_QUERY)
    options = SequenceOptions(ks=(1, 3))
    result = evaluate_float(ckpt, dataset.traversal(query), dataset.place_ids, query, options, truth=truth)
    assert dicts(result.rows) == rows  # the command scored against the file
    # a hand-made GT-exact manifest: query j under the reference's place id j + OFFSET, exact match
    manifest_rows = readout_rows(
        ckpt.calibration,
        result.query_counts,
        ckpt.reference_place_ids,
        dataset.place_ids + OFFSET,
        options,
        ckpt.config,
    )
    assert dicts(manifest_rows) == rows
    by_index = readout_rows(
        ckpt.calibration,
        result.query_counts,
        ckpt.reference_place_ids,
        dataset.place_ids,
        options,
        ckpt.config,
    )
    assert max(r["accuracy"] for r in rows) > 0 and dicts(by_index) != rows  # the index score was the wrong one

    predictions = tmp_path / "p.jsonl"  # issue 31: the truth column holds the file's places, not the frame index
    assert main(["evaluate", str(ckpt_path), "--query", query, "--k", "1,3", "--predictions", str(predictions)]) == 0
    lines = [json.loads(line) for line in predictions.read_text().splitlines()]
    assert {line["query"]: line["truth"] for line in lines} == {q: [q + OFFSET] for q in range(N_QUERY)}
    assert all(line["correct"] == (line["place_id"] in line["truth"]) for line in lines)
    assert main(["evaluate", str(ckpt_path), "--query", query, "--match-window", "2", "--quiet"]) == 2
    assert "says which reference frames match" in capsys.readouterr().err


def test_simulate_verify_and_calibrate_score_against_the_file(tmp_path, capsys):
    data = tmp_path / "data"
    reference, query = lens_layout(data)
    ckpt_path = tmp_path / "net.npz"
    assert main(["train", "--data", str(data), "--reference", reference, *TINY, "--out", str(ckpt_path)]) == 0
    float_rows = evaluate_json(capsys, str(ckpt_path), "--query", query)
    assert main(["quantize", str(ckpt_path), "--bits", "8", "--out", str(tmp_path / "q"), "--quiet"]) == 0
    model = tmp_path / "q" / "model_8bit_per-neuron_max.npz"
    capsys.readouterr()
    assert main(["simulate", str(model), "--query", query, "--json", "--quiet"]) == 0
    simulated = json.loads(capsys.readouterr().out)["results"]
    assert simulated[0]["n_queries"] == N_QUERY and abs(simulated[0]["accuracy"] - float_rows[0]["accuracy"]) <= 0.2
    report = tmp_path / "rep"
    code = main(["verify", str(ckpt_path), "--bits", "8", "--query", query, "--report", str(report), "--quiet"])
    assert code in (0, 1), capsys.readouterr().err
    verified = json.loads((report / "report.json").read_text())
    by_key = {(r["strategy"], r["k"]): r for r in verified["runs"][0]["float"]["metrics"]}
    assert all(by_key[(r["strategy"], r["k"])] == r for r in float_rows)  # verify scored by the file too
    assert verified["settings"]["ground_truth"].endswith("sunset2_sunset1_GT.npy")
    assert main(["report", str(report), "--out", str(tmp_path / "again")]) in (0, 1)  # the report reads back
    point = tmp_path / "point.json"
    argv = ["localize", str(ckpt_path), "--calibrate", query, "--precision", "0.01", "--operating-point", str(point)]
    argv += ["--quiet"]
    capsys.readouterr()
    assert main(argv) == 0, capsys.readouterr().err
    stored = json.loads(point.read_text())
    assert stored["ground_truth"].endswith("sunset2_sunset1_GT.npy") and stored["n_queries"] == N_QUERY


def test_different_lengths_without_ground_truth_are_refused_by_every_command(tmp_path, capsys):
    data = tmp_path / "data"
    offset_route(data, "sunset1", "sunset2")  # no ground-truth file
    ckpt_path = tmp_path / "net.npz"
    assert main(["train", "--data", str(data), "--reference", "sunset1", *TINY, "--out", str(ckpt_path)]) == 0
    for argv in (
        ["evaluate", str(ckpt_path), "--query", "sunset2"],
        ["localize", str(ckpt_path), "--calibrate", "sunset2", "--operating-point", str(tmp_path / "p.json")],
    ):
        capsys.readouterr()
        assert main([*argv, "--quiet"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "not index-aligned and no ground-truth file" in err[0] and str(data) in err[0]
    assert not (tmp_path / "p.json").exists()


def test_a_query_may_match_several_references():
    truth = GroundTruth(np.array([[1, 0], [1, 1], [0, 1]], dtype=bool), "gt")
    predicted = np.ma.MaskedArray([1, 0, 2, 1], mask=[False, False, False, True])
    assert truth.correct(predicted, np.array([0, 1, 1, 1])).tolist() == [True, False, True, False]
    assert [t.tolist() for t in truth.true_places(np.array([0, 1]))] == [[0, 1], [1, 2]]


def test_no_output_replaces_the_ground_truth_it_was_scored_by(tmp_path, capsys):
    data = tmp_path / "data"
    truth = offset_route(data, "sunset1", "sunset2")
    pairs = "".join(f"{q},{r}\n" for r, q in zip(*np.nonzero(truth), strict=True))
    gt = data / "sunset1_sunset2_GT.csv"
    gt.write_text("query,reference\n" + pairs, encoding="utf-8")
    ckpt_path = tmp_path / "net.npz"
    assert main(["train", "--data", str(data), "--reference", "sunset1", *TINY, "--out", str(ckpt_path)]) == 0
    for argv in (
        ["evaluate", str(ckpt_path), "--query", "sunset2", "--predictions", str(gt)],
        ["localize", str(ckpt_path), "--calibrate", "sunset2", "--precision", "0.1", "--operating-point", str(gt)],
    ):
        capsys.readouterr()
        assert main([*argv, "--quiet"]) == 2
        assert "one of this command's input files" in capsys.readouterr().err
    train = ["train", "--data", str(data), "--reference", "sunset1", *TINY, "--out", str(gt), "--force"]
    assert main(train) == 2 and "one of this command's input files" in capsys.readouterr().err
    assert gt.read_text(encoding="utf-8") == "query,reference\n" + pairs


def test_an_unequal_lens_route_gets_baselines_truth_named_and_modules_by_its_ground_truth(tmp_path, capsys):
    """Issue 45: on traversals of different lengths --baseline prints cosine and SAD, every result names the truth,
    and the per-module rows count each query in the module of its true place (ground truth), not at j // P."""
    data = tmp_path / "data"
    reference, query = lens_layout(data)
    ckpt_path = tmp_path / "net.npz"
    ensemble = [*TINY, "--module-size", "10"]
    assert main(["train", "--data", str(data), "--reference", reference, *ensemble, "--out", str(ckpt_path)]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(ckpt_path), "--query", query, "--k", "1", "--baseline", "--json", "--quiet"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert {"sad", "cosine"} <= {row["strategy"] for row in result["results"]}
    assert result["truth"] == f"ground truth: {data / 'sunset2_sunset1_GT.npy'}"
    # query j is reference place j + 6: modules of 10 references hold queries 0-3, 4-13 and 14-19
    assert [m["n_queries"] for m in result["modules"]] == [4, 10, 6]
    assert sum(m["n_queries"] for m in result["modules"]) == N_QUERY
    assert main(["evaluate", str(ckpt_path), "--query", query, "--k", "1", "--quiet"]) == 0
    assert f"scored against the ground truth: {data / 'sunset2_sunset1_GT.npy'}" in capsys.readouterr().out


def test_a_manifest_beside_a_ground_truth_file_is_refused_in_one_line(tmp_path, capsys):
    data = tmp_path / "data"
    reference, query = lens_layout(data)
    rows = "".join(f"{p},{reference}/image_{p:04d}.png,{reference}/image_{p:04d}.png\n" for p in range(N_QUERY))
    (data / "places.csv").write_text(f"place_id,{reference},{query}\n" + rows, encoding="utf-8")
    ckpt_path = tmp_path / "net.npz"
    assert main(["train", "--data", str(data), "--reference", reference, *TINY, "--out", str(ckpt_path)]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(ckpt_path), "--query", query, "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "is ambiguous" in err and "sunset2_sunset1_GT.npy" in err and len(err.strip().splitlines()) == 1


def test_each_command_opens_the_ground_truth_file_once(tmp_path, capsys, monkeypatch):
    """Issue 42: load, fingerprint and scoring ask one reader, so a command opens the file once (each command
    is a process of its own: the memo is cleared before each). Two traversals of equal length with a file
    beside them: loaded together, the file was read three times before (load, fingerprint, scoring)."""
    from vprsnn_export.data import groundtruth

    data = tmp_path / "data"
    route = synthetic_route(N_REFERENCE, ("summer", "winter"))
    write_traversal(data / "sunset1", route["summer"])
    write_traversal(data / "sunset2", route["winter"])
    gt = data / "sunset2_sunset1_GT.npy"
    np.save(gt, np.eye(N_REFERENCE, dtype=np.int64))
    ckpt = tmp_path / "net.npz"
    opened: list[Path] = []
    read_bytes = Path.read_bytes
    monkeypatch.setattr(Path, "read_bytes", lambda self: opened.append(self.resolve()) or read_bytes(self))
    train = ["train", "--data", str(data), "--reference", "sunset1", *TINY, "--out", str(ckpt)]
    commands = {
        "train --adapt-from": [*train, "--adapt-from", "sunset2", "--adapt", "gain", "--adapt-pairing", "truth"],
        "evaluate --baseline": ["evaluate", str(ckpt), "--query", "sunset2", "--k", "1,3", "--baseline", "--quiet"],
        "verify": ["verify", str(ckpt), "--query", "sunset2", "--bits", "8", "--k", "1,3", "--targets", "none",
                   "--report", str(tmp_path / "v"), "--quiet"],
        "localize --calibrate": ["localize", str(ckpt), "--calibrate", "sunset2", "--k", "3", "--precision", "0.1",
                                 "--quiet"],
    }  # fmt: skip
    for name, argv in commands.items():
        groundtruth._READ.clear()
        opened.clear()
        assert main(argv) in (0, 2), f"{name}: {capsys.readouterr().err}"
        assert opened.count(gt.resolve()) == 1, f"{name} opened the ground truth {opened.count(gt.resolve())} times"
    capsys.readouterr()
