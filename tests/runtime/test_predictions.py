"""Per-query predictions: the decisions behind the metric rows, as a typed result, CSV and JSON lines."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from vprsnn_export.cli import main
from vprsnn_export.data.truth import EXACT, GroundTruth
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.io.checkpoint import save_checkpoint
from vprsnn_export.readout.scored import Scored
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.evaluation import evaluate_float
from vprsnn_export.runtime.predictions import network_predictions, predictions


def test_each_column_reproduces_its_metric_row(trained, tmp_path):
    ckpt, data = trained
    options = SequenceOptions(ks=(1, 3), tolerance=1)
    result = evaluate_float(ckpt, data.traversal("winter"), data.place_ids, "winter", options)
    found = network_predictions(ckpt, result.query_counts, data.place_ids, options)
    assert found.n_queries == 24 and [(d.strategy, d.k) for d in found.decided] == [
        (r["strategy"], r["k"]) for r in result.rows
    ]
    for row in result.rows:
        column = found.column(row["strategy"], row["k"])
        assert column.correct is not None and column.correct.mean() == pytest.approx(row["accuracy"])
        assert np.all((column.place_id >= 0) | (column.confidence == 0))
    rows = list(csv.DictReader(found.write(tmp_path / "p.csv").open()))
    lines = [json.loads(line) for line in found.write(tmp_path / "p.jsonl").read_text().splitlines()]
    assert len(rows) == len(lines) == 24 * 4
    assert lines[0] == {**found.rows()[0]} and rows[0]["strategy"] == "standard" and rows[0]["query"] == "0"
    assert predictions(result.scored).rows() == found.rows()  # the evaluation's own columns, decided once
    unlabelled = network_predictions(ckpt, result.query_counts, None, options)
    assert unlabelled.truth is None and unlabelled.rows()[0]["correct"] is None
    with pytest.raises(InvalidValueError, match=".csv or .jsonl"):
        found.write(tmp_path / "p.txt")


def test_evaluate_writes_predictions(trained, tmp_path, capsys):
    ckpt, _ = trained
    path = save_checkpoint(tmp_path / "net.npz", ckpt)
    out = tmp_path / "winter.jsonl"
    argv = ["evaluate", str(path), "--query", "winter", "--k", "1,3", "--quiet", "--json"]
    assert main([*argv, "--predictions", str(out)]) == 0
    rows = json.loads(capsys.readouterr().out)["results"]
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    wprob3 = [line for line in lines if (line["strategy"], line["k"]) == ("wprob", 3)]
    assert len(wprob3) == 24 and all(line["truth"] == [line["query"]] for line in wprob3)
    expected = next(r["accuracy"] for r in rows if (r["strategy"], r["k"]) == ("wprob", 3))
    assert np.mean([line["correct"] for line in wprob3]) == pytest.approx(expected)
    assert main([*argv, "--predictions", str(tmp_path / "p.txt")]) == 2
    assert ".csv or .jsonl" in capsys.readouterr().err


def test_the_truth_column_holds_the_ground_truths_places_not_the_frame_index(tmp_path):
    """Issue 31: with a ground truth, a query's truth is the reference place ids the file names for it (several,
    one, or none: empty, said so), never the query's frame index; ``correct`` is membership in it."""
    matrix = np.zeros((6, 3), dtype=bool)
    matrix[[4, 5], 0] = True  # query 0 matches references 4 and 5
    matrix[1, 1] = True
    scores = {name: np.eye(6)[[5, 2, 3]] for name in ("standard", "weighted", "wprob")}
    found = predictions(
        Scored.of(scores, {1: scores["wprob"]}, np.arange(6), np.arange(3), GroundTruth(matrix, "gt.npy"))
    )
    assert [t.tolist() for t in found.truth] == [[4, 5], [1], []]
    rows = [r for r in found.rows() if r["strategy"] == "wprob"]
    assert [(r["truth"], r["place_id"], r["correct"]) for r in rows] == [
        ([4, 5], 5, True),
        ([1], 2, False),
        ([], 3, False),
    ]
    assert [r["note"] for r in rows] == ["", "", "the ground truth (gt.npy) names no reference place for this query"]
    lines = list(csv.DictReader(found.write(tmp_path / "p.csv").open()))
    assert [line["truth"] for line in lines if line["strategy"] == "wprob"] == ["4 5", "1", ""]
    aligned = predictions(Scored.of(scores, {1: scores["wprob"]}, np.arange(6), np.array([5, 2, 0]), EXACT))
    assert [r["truth"] for r in aligned.rows() if r["strategy"] == "wprob"] == [[5], [2], [0]]
