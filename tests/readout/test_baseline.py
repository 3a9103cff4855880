"""The no-learning SAD baseline."""

from __future__ import annotations

import numpy as np
import pytest

from vprsnn_export.readout import baseline
from vprsnn_export.readout.aggregation import aggregate
from vprsnn_export.readout.assignment import NO_MATCH
from vprsnn_export.readout.baseline import sad_distances, sad_distribution
from vprsnn_export.readout.strategies import decide


def test_sad_distances_hand_and_brute_force(monkeypatch: pytest.MonkeyPatch) -> None:
    ref = np.array([[0.0, 1.0], [1.0, 1.0], [0.5, 0.0]])
    qry = np.array([[0.0, 0.0], [1.0, 1.0]])
    np.testing.assert_allclose(sad_distances(ref, qry), [[1.0, 2.0, 0.5], [1.0, 0.0, 1.5]])
    rng = np.random.default_rng(0)
    ref = rng.random((13, 20))
    qry = rng.random((17, 20))
    brute = np.abs(qry[:, None, :] - ref[None, :, :]).sum(axis=2)
    np.testing.assert_allclose(sad_distances(ref, qry), brute)
    monkeypatch.setattr(baseline, "_MAX_ELEMENTS", 13 * 20 * 2)  # 2 queries per chunk
    np.testing.assert_allclose(sad_distances(ref, qry), brute)
    with pytest.raises(ValueError):
        sad_distances(ref, qry[:, :5])


def test_sad_distribution_hand_example_and_decision() -> None:
    d = np.array([[1.0, 3.0, 5.0], [2.0, 2.0, 2.0]])
    dist = sad_distribution(d)
    # similarity -d min-max normalised: [1, 0.5, 0] -> L1: [2/3, 1/3, 0]
    np.testing.assert_allclose(dist[0], [2 / 3, 1 / 3, 0.0])
    np.testing.assert_array_equal(dist[1], np.full(3, 1 / 3))
    pred, conf = decide(dist, "wprob")
    assert pred.tolist() == [0, NO_MATCH]
    np.testing.assert_allclose(conf, [2 / 3, 0.0])


def test_baseline_pipeline_with_aggregation() -> None:
    rng = np.random.default_rng(1)
    ref = rng.random((30, 16))
    true = np.arange(2, 22)
    qry = ref[true] + rng.normal(0, 0.35, (20, 16))
    dist = sad_distribution(sad_distances(ref, qry))
    agg = aggregate(dist, 5, 1.0)
    pred, _ = decide(agg, "wprob")
    assert np.mean(pred[4:] == true[4:]) >= np.mean(dist.argmax(axis=1)[4:] == true[4:])
    assert np.mean(pred[4:] == true[4:]) >= 0.9


def test_cosine_similarities_hand_example_and_zero_image() -> None:
    from vprsnn_export.readout.baseline import cosine_similarities

    ref = np.array([[1.0, 0.0], [1.0, 1.0], [0.0, 0.0]])
    qry = np.array([[2.0, 0.0], [0.0, 3.0]])
    expected = [[1.0, 1 / np.sqrt(2), 0.0], [0.0, 1 / np.sqrt(2), 0.0]]
    np.testing.assert_allclose(cosine_similarities(ref, qry), expected)
    with pytest.raises(ValueError, match="pixels"):
        cosine_similarities(ref, qry[:, :1])


def test_diagonal_sums_add_the_previous_frames_shifted_by_the_velocity() -> None:
    from vprsnn_export.readout.baseline import diagonal_sums

    scores = np.arange(12, dtype=np.float64).reshape(3, 4)
    out = diagonal_sums(scores, 2)
    # query 0 has no previous frame; query j adds frame j-1 at place l-1 (0 beyond the map)
    np.testing.assert_allclose(out[0], scores[0])
    np.testing.assert_allclose(out[2], scores[2] + np.concatenate([[0.0], scores[1, :3]]))
    np.testing.assert_allclose(diagonal_sums(scores, 1), scores)
    np.testing.assert_allclose(diagonal_sums(scores, 2, velocity=0.0)[1], scores[1] + scores[0])
    with pytest.raises(ValueError, match="k must be"):
        diagonal_sums(scores, 0)
    with pytest.raises(ValueError, match="non-negative"):
        diagonal_sums(-scores, 2)


def test_sad_similarities_keep_the_nearest_place_and_the_margin() -> None:
    from vprsnn_export.readout.baseline import nearest_neighbour, sad_similarities

    d = np.array([[3.0, 1.0, 2.0], [5.0, 5.0, 4.0]])
    s = sad_similarities(d)
    assert np.all(s >= 0)
    for a, b in zip(nearest_neighbour(s), nearest_neighbour(-d), strict=True):
        np.testing.assert_allclose(a, b)


def test_nearest_neighbour_margin_confidence_ties_and_flat_rows() -> None:
    from vprsnn_export.readout.baseline import nearest_neighbour

    pred, conf = nearest_neighbour(np.array([[0.1, 0.9, 0.5], [0.3, 0.3, 0.3], [0.7, 0.7, 0.1]]))
    assert pred.tolist() == [1, -1, 0]
    np.testing.assert_allclose(conf, [0.4, 0.0, 0.0])


def test_cosine_baseline_rows_in_an_evaluation_equal_the_direct_computation() -> None:
    from vprsnn_export.data.truth import EXACT
    from vprsnn_export.readout.baseline import cosine_similarities, nearest_neighbour
    from vprsnn_export.readout.metrics import is_correct, pr_metrics, predicted_place_ids
    from vprsnn_export.readout.scoring import nearest_neighbour_rows
    from vprsnn_export.readout.sequence import SequenceOptions

    rng = np.random.default_rng(3)
    ref = rng.random((12, 20))
    qry = ref + 3.0 * rng.random((12, 20))
    ids = np.arange(100, 112)
    rows = nearest_neighbour_rows(cosine_similarities(ref, qry), "cosine", ids, ids, SequenceOptions(), EXACT)
    pred, conf = nearest_neighbour(cosine_similarities(ref, qry))
    direct = pr_metrics(is_correct(predicted_place_ids(pred, ids), ids, 0), conf)
    assert [r.to_dict() for r in rows] == [{"strategy": "cosine", "k": 1, **direct}]
    assert 0.0 < rows[0].accuracy < 1.0
