"""Velocity sources: SequenceOptions.aggregate routing and the envelope rows of every Table IV condition."""

from __future__ import annotations

import numpy as np
import pytest

from experiments import envelope
from experiments.common import summarise_rows
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.readout.aggregation import aggregate, estimate_velocity, smooth_velocity, track_velocity
from vprsnn_export.readout.sequence import SequenceOptions

GRID = (-1.0, -0.5, 0.5, 1.0, 1.5)


def _route(n: int, seed: int) -> np.ndarray:
    """A noisy distribution per frame of a traversal at 1 place per frame (frame j is at place j)."""
    rng = np.random.default_rng(seed)
    prob = rng.random((n, n)) * 0.3
    prob[np.arange(n), np.arange(n)] += 1.0
    return prob / prob.sum(axis=1, keepdims=True)


def test_aggregated_routes_each_velocity_source() -> None:
    prob = _route(30, seed=1)
    given = SequenceOptions(velocity=1.0).aggregate(prob, 5)
    np.testing.assert_array_equal(given, aggregate(prob, 5, 1.0))
    window = SequenceOptions(velocity_candidates=GRID, velocity_estimate="window").aggregate(prob, 5)
    np.testing.assert_array_equal(window, estimate_velocity(prob, 5, np.asarray(GRID))[1])
    options = SequenceOptions(
        velocity_candidates=GRID,
        velocity_estimate="track",
        velocity_span=4,
        velocity_length=6,
        velocity_memory=8,
    )
    tracked = options.aggregate(prob, 5)
    expected = track_velocity(prob, 5, np.asarray(GRID), 4, length=6, memory=8)[1]
    np.testing.assert_array_equal(tracked, expected)
    assert options.aggregate(prob, 1) is prob
    options = SequenceOptions(velocity_candidates=GRID, velocity_estimate="smooth", velocity_lag=3)
    smoothed = options.aggregate(prob, 5)
    np.testing.assert_array_equal(smoothed, smooth_velocity(prob, 5, np.asarray(GRID), 10, lag=3)[1])


def test_unknown_velocity_estimate_is_a_clear_error() -> None:
    with pytest.raises(
        InvalidValueError, match="velocity estimate: unknown 'oracle'; choose from smooth, track, window"
    ):
        SequenceOptions(velocity_candidates=GRID, velocity_estimate="oracle")  # refused when the options are built


def test_envelope_rows_cover_every_condition_method_and_source() -> None:
    n = 40
    ids = np.arange(500, 500 + n)
    distributions = {"wprob": _route(n, seed=3), "sad": _route(n, seed=4)}
    rows = envelope.envelope_rows(distributions, ids, ids, np.random.default_rng(0))
    names = [name for name, *_ in envelope.conditions(n, np.random.default_rng(0))]
    assert len(names) == 12 and any("reverse" in name for name in names)
    assert {(r["condition"], r["method"], r["velocity"]) for r in rows} == {
        (name, method, source) for name in names for method in envelope.METHODS for source in envelope.SOURCES
    }
    by_key = {(r["condition"], r["method"], r["velocity"]): r for r in rows}
    # a wrong given velocity or a reversal breaks the given source; the tracker does not need it
    reverse = next(name for name in names if "reverse" in name)
    assert by_key[(reverse, "wprob", "given")]["accuracy"] < 0.5
    assert by_key[(reverse, "wprob", "tracked")]["accuracy"] > 0.8
    assert by_key[(reverse, "wprob", "tracked")]["velocity_median"] == -1.0
    assert by_key[(reverse, "wprob", "smoothed")]["accuracy"] > 0.8
    assert by_key[(reverse, "wprob", "smoothed")]["velocity_median"] == -1.0
    mismatch = next(name for name in names if "-50%" in name)
    assert by_key[(mismatch, "wprob", "tracked")]["accuracy"] > 0.8
    assert by_key[(mismatch, "wprob", "smoothed")]["accuracy"] > 0.8
    summary = summarise_rows([rows], envelope.KEYS)
    table = envelope.compact_table(summary)
    assert table.count("\n") == 1 + len(names)
    assert "nan" not in table.lower()
