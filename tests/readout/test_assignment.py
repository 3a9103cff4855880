"""Neuron assignment strategies (paper Sec. III-E, eq. 9-13) and decisions."""

from __future__ import annotations

import numpy as np
import pytest

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.readout.assignment import (
    NO_MATCH,
    missing_spikes_penalty,
    share_confidence,
    standard_assignment,
    standard_scores,
    weighted_matrix,
    weighted_scores,
    wprob_distribution,
)
from vprsnn_export.readout.strategies import STRATEGIES, decide, strategy_scores

# Hand example used below: 3 neurons x 3 places.
SR = np.array([[2, 0, 2], [0, 3, 0], [1, 1, 1]], dtype=float)


def _weighted_loops(sr: np.ndarray, sq: np.ndarray, gamma: float) -> np.ndarray:
    """Literal, loop-by-loop transcription of eq. 9-11 (reference for the vectorised code)."""
    n, p = sr.shape
    s2 = np.zeros((n, p))
    for i in range(n):
        omega = sum(1 for place in range(p) if sr[i, place] > 0)
        total = sr[i].sum()
        for place in range(p):
            s1 = sr[i, place] / omega if omega > gamma * p else sr[i, place]
            s2[i, place] = s1 * sr[i, place] / total if total > 0 else 0.0
    out = np.zeros((sq.shape[0], p))
    for q in range(sq.shape[0]):
        for place in range(p):
            raw = sum(sq[q, i] * s2[i, place] for i in range(n))
            col = sr[:, place].sum()
            act = sum(sr[m, place] for m in range(n) if sq[q, m] > 0)
            out[q, place] = raw * (act / col) if col > 0 else 0.0
    return out


def test_standard_assignment_ties_and_silent_neurons() -> None:
    sr = np.array([[0, 5, 5], [0, 0, 0], [7, 1, 0]], dtype=float)
    a = standard_assignment(sr)
    # tie between places 1 and 2 -> lowest index; silent neuron -> no place
    np.testing.assert_array_equal(a, [[0, 1, 0], [0, 0, 0], [1, 0, 0]])
    sq = np.array([[1, 100, 2], [0, 9, 0]], dtype=float)
    np.testing.assert_array_equal(standard_scores(sr, sq), [[2, 1, 0], [0, 0, 0]])


def test_standard_scores_hand_example() -> None:
    sq = np.array([[1, 2, 3]], dtype=float)
    # neuron 0 -> place 0 (tie 0/2), neuron 1 -> place 1, neuron 2 -> place 0 (all tied)
    np.testing.assert_array_equal(standard_scores(SR, sq), [[4, 2, 0]])


def test_weighted_hand_example() -> None:
    # omega = [2, 1, 3] and gamma * P = 1.5: neurons 0 and 2 are divided by omega.
    s2 = weighted_matrix(SR, 0.5)
    np.testing.assert_allclose(s2, [[0.5, 0, 0.5], [0, 3, 0], [1 / 9, 1 / 9, 1 / 9]])
    sq = np.array([[1, 0, 2]], dtype=float)
    # Active = {0, 2}: penalty = [3/3, 1/4, 3/3]
    np.testing.assert_allclose(missing_spikes_penalty(SR, sq), [[1, 0.25, 1]])
    np.testing.assert_allclose(weighted_scores(SR, sq, 0.5), [[13 / 18, 1 / 18, 13 / 18]])
    dist = wprob_distribution(weighted_scores(SR, sq, 0.5))
    np.testing.assert_allclose(dist, [[0.5, 0.0, 0.5]])
    pred, conf = decide(dist, "wprob")
    assert pred.tolist() == [0] and conf.tolist() == [0.5]


def test_weighted_matches_literal_equations() -> None:
    rng = np.random.default_rng(0)
    sr = rng.integers(0, 4, size=(12, 7)).astype(float) * (rng.random((12, 7)) < 0.5)
    sr[3] = 0.0  # silent neuron
    sr[:, 5] = 0.0  # place never seen during calibration -> penalty 0
    sq = rng.integers(0, 3, size=(6, 12)).astype(float)
    sq[2] = 0.0  # silent query
    for gamma in (0.0, 0.3, 0.6, 1.0):
        np.testing.assert_allclose(weighted_scores(sr, sq, gamma), _weighted_loops(sr, sq, gamma))
    assert np.all(weighted_scores(sr, sq, 0.3)[2] == 0)
    assert np.all(weighted_scores(sr, sq, 0.3)[:, 5] == 0)


def test_wprob_distribution_and_uniform_choice() -> None:
    scores = np.array([[1.0, 3.0, 2.0], [4.0, 4.0, 4.0], [0.0, 0.0, 0.0]])
    dist = wprob_distribution(scores)
    np.testing.assert_allclose(dist[0], [0.0, 2 / 3, 1 / 3])
    np.testing.assert_array_equal(dist[1:], np.full((2, 3), 1 / 3))
    np.testing.assert_allclose(dist.sum(axis=1), 1.0)
    pred, conf = decide(dist, "wprob")
    assert pred.tolist() == [1, NO_MATCH, NO_MATCH]
    np.testing.assert_allclose(conf, [2 / 3, 0, 0])


def test_share_confidence_and_decide_standard_weighted() -> None:
    scores = np.array([[1.0, 3.0, 0.0], [2.0, 2.0, 0.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(share_confidence(scores), [0.75, 0.5, 0.0])
    for strategy in ("standard", "weighted"):
        pred, conf = decide(scores, strategy)
        assert pred.dtype == np.int64
        assert pred.tolist() == [1, 0, NO_MATCH]  # tie -> lowest index
        np.testing.assert_allclose(conf, [0.75, 0.5, 0.0])


def test_strategy_scores_dispatch() -> None:
    sq = np.array([[1, 0, 2], [0, 0, 0]], dtype=float)
    np.testing.assert_array_equal(strategy_scores(SR, sq, "standard"), standard_scores(SR, sq))
    np.testing.assert_array_equal(strategy_scores(SR, sq, "weighted", 0.5), weighted_scores(SR, sq, 0.5))
    dist = strategy_scores(SR, sq, "wprob", 0.5)
    np.testing.assert_array_equal(dist, wprob_distribution(weighted_scores(SR, sq, 0.5)))
    assert STRATEGIES.names() == ("standard", "weighted", "wprob")
    for strategy in STRATEGIES:
        pred, _ = decide(strategy_scores(SR, sq, strategy, 0.5), strategy)
        assert pred[1] == NO_MATCH  # a silent query never matches


def test_invalid_inputs() -> None:
    sq = np.ones((2, 3))
    with pytest.raises(ValueError):
        strategy_scores(SR, sq, "weighted")  # gamma missing
    with pytest.raises(InvalidValueError, match="unknown 'argmax'; choose from standard, weighted, wprob"):
        strategy_scores(SR, sq, "argmax", 0.5)
    with pytest.raises(InvalidValueError, match="strategy: unknown 'bogus'"):
        decide(np.ones((2, 3)), "bogus")
    with pytest.raises(ValueError):
        weighted_scores(SR, sq, 1.5)
    with pytest.raises(ValueError):
        standard_scores(SR, np.ones((2, 4)))  # neuron count mismatch
    with pytest.raises(ValueError):
        standard_scores(-SR, sq)


def test_outputs_are_float64() -> None:
    sr = SR.astype(np.int32)
    sq = np.array([[1, 0, 2]], dtype=np.int64)
    for strategy in STRATEGIES:
        assert strategy_scores(sr, sq, strategy, 0.5).dtype == np.float64
