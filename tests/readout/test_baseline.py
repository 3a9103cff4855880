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
