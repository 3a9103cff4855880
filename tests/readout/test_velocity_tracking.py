"""Velocity tracked (track_velocity) or smoothed with a fixed lag (smooth_velocity) over the query stream."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from vprsnn_export.readout import aggregation
from vprsnn_export.readout.aggregation import (
    _aggregate_scored,
    aggregate,
    centre_of_best,
    estimate_velocity,
    lagged_sum,
    smooth_velocity,
    stream_contrast,
    track_velocity,
    window_scores,
)

GRID = np.round(np.arange(-2.0, 2.0001, 0.25), 2)


def _stream(
    n_queries: int,
    n_places: int,
    velocity: float,
    start: float,
    seed: int,
    positions: np.ndarray | None = None,
    decoys: float = 0.7,
) -> tuple[np.ndarray, np.ndarray]:
    """Hard noisy per-frame distributions of a constant-velocity traversal: (prob, true place index).

    A weak bump sits at the true continuous position; on ``decoys`` of the
    frames a stronger peak sits at a random place, so single frames and single
    short windows are often wrong.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n_queries, dtype=float) if positions is None else positions
    pos = start + velocity * t
    places = np.arange(n_places, dtype=float)
    prob = rng.random((n_queries, n_places)) * 0.5 + 0.5 * np.exp(-0.5 * ((places - pos[:, None]) / 0.7) ** 2)
    decoy = rng.random(n_queries) < decoys
    prob[np.flatnonzero(decoy), rng.integers(0, n_places, n_queries)[decoy]] += 1.0
    return prob / prob.sum(axis=1, keepdims=True), np.rint(pos).astype(int)


@pytest.mark.parametrize(
    ("velocity", "start"),
    [(1.0, 3), (2.0, 2), (-1.0, 75), (0.5, 10.2)],
)
def test_tracking_recovers_a_known_velocity(velocity: float, start: float) -> None:
    prob, true = _stream(60, 130, velocity, start, seed=3)
    settled = slice(12, None)  # after the first span of windows
    v_hat, agg = track_velocity(prob, 5, GRID, span=10)
    assert np.all(v_hat[settled] == velocity)
    assert np.mean(agg[settled].argmax(axis=1) == true[settled]) >= 0.95
    # the per-window search on the same stream is fooled more often
    v_window, _ = estimate_velocity(prob, 5, GRID)
    assert np.mean(v_window[settled] == velocity) < np.mean(v_hat[settled] == velocity)


def test_tracking_with_dropped_frames_uses_frame_positions() -> None:
    kept = np.sort(np.random.default_rng(7).choice(100, 60, replace=False)).astype(float)
    prob, true = _stream(60, 110, 1.0, 4, seed=8, positions=kept)
    v_hat, agg = track_velocity(prob, 5, GRID, span=10, frame_positions=kept)
    assert np.all(v_hat[12:] == 1.0)
    assert np.mean(agg[12:].argmax(axis=1) == true[12:]) >= 0.95
    np.testing.assert_array_equal(agg, aggregate(prob, 5, v_hat, frame_positions=kept))


def test_window_scores_are_the_aggregate_peaks_of_every_candidate() -> None:
    prob, _ = _stream(20, 30, 1.0, 2, seed=1)
    t = np.cumsum(np.r_[0.0, np.random.default_rng(2).integers(1, 3, 19)])
    for rule in ("product", "sum"):
        e = window_scores(prob, 4, GRID, rule, t)
        assert e.shape == (20, GRID.size)
        for c, v in enumerate(GRID):
            expected = _aggregate_scored(prob, 4, float(v), rule, t, 1e-6)[1]
            np.testing.assert_array_equal(e[:, c], expected)
    # k = 1: every candidate scores the frame's own peak
    np.testing.assert_array_equal(window_scores(prob, 1, GRID), np.repeat(prob.max(axis=1)[:, None], GRID.size, 1))
    # some windows only (a stream scores its newest): the very rows of the full table, in the order asked
    for k in (1, 4):
        full = window_scores(prob, k, GRID, "product", t)
        some = np.array([19, 0, 7])
        np.testing.assert_array_equal(window_scores(prob, k, GRID, "product", t, windows=some), full[some])


def test_tracked_velocity_is_the_argmax_of_the_causal_moving_sum() -> None:
    prob, _ = _stream(30, 40, 1.0, 2, seed=5, decoys=0.9)
    span, length, memory = 4, 6, 12
    e = window_scores(stream_contrast(prob, memory), length, GRID)
    expected = np.array([GRID[np.argmax(e[max(0, j - span + 1) : j + 1].sum(axis=0))] for j in range(30)])
    v_hat, agg = track_velocity(prob, 3, GRID, span=span, length=length, memory=memory)
    np.testing.assert_array_equal(v_hat, expected)
    np.testing.assert_array_equal(agg, aggregate(prob, 3, v_hat))
    # the default trajectory length is 2k
    default = track_velocity(prob, 3, GRID, span=span, memory=memory)[0]
    np.testing.assert_array_equal(default, track_velocity(prob, 3, GRID, span=span, length=6, memory=memory)[0])
    # span 1, length k and no contrast is the per-window search
    v1, agg1 = track_velocity(prob, 3, GRID, span=1, length=3, memory=0)
    v_window, agg_window = estimate_velocity(prob, 3, GRID)
    np.testing.assert_array_equal(v1, v_window)
    np.testing.assert_array_equal(agg1, agg_window)


def test_tracking_is_causal() -> None:
    prob, _ = _stream(40, 60, 1.0, 2, seed=6)
    v_hat, agg = track_velocity(prob, 5, GRID, span=8)
    changed = prob.copy()
    changed[25:] = np.random.default_rng(0).random((15, 60))
    v_changed, agg_changed = track_velocity(changed, 5, GRID, span=8)
    np.testing.assert_array_equal(v_changed[:25], v_hat[:25])
    np.testing.assert_array_equal(agg_changed[:25], agg[:25])


def test_tie_goes_to_the_first_candidate() -> None:
    prob = np.full((6, 5), 0.2)
    v_hat, _ = track_velocity(prob, 3, [0.5, -1.0, 1.0], span=3)
    assert np.all(v_hat == 0.5)


def test_every_pair_is_scored_at_once(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[int] = []
    original = aggregation._shift_rows

    def counting(*args):
        calls.append(len(args[1]))
        return original(*args)

    monkeypatch.setattr(aggregation, "_shift_rows", counting)
    prob, _ = _stream(30, 40, 1.0, 2, seed=9)
    window_scores(prob, 5, GRID)
    assert calls == [30 * GRID.size]  # one vectorised call, no loop per query or per candidate
    calls.clear()
    monkeypatch.setattr(aggregation, "_MAX_ELEMENTS", 5 * 40 * 100)  # chunks of 100 (query, candidate) rows
    chunked = window_scores(prob, 5, GRID)
    assert calls == [100] * 5 + [30 * GRID.size - 500]
    monkeypatch.undo()
    np.testing.assert_array_equal(chunked, window_scores(prob, 5, GRID))


def test_no_ground_truth_in_signatures() -> None:
    allowed = {"prob", "k", "candidates", "span", "rule", "frame_positions", "eps", "length", "memory", "lag"}
    allowed |= {"nearest", "scores", "totals", "windows"}  # windows: stream indices, not places
    for fn in (window_scores, track_velocity, smooth_velocity, stream_contrast, lagged_sum, centre_of_best):
        params = set(inspect.signature(fn).parameters)
        assert params <= allowed, params


def test_stream_contrast_by_hand() -> None:
    prob = np.array([[0.5, 0.5, 0.0], [0.2, 0.6, 0.2], [0.0, 0.5, 0.5]])
    out = stream_contrast(prob, 2)
    np.testing.assert_array_equal(out[0], [0.5, 0.5, 0.0])  # a frame alone: P / P = 1 where P > 0
    ratio = prob[1] / ((prob[0] + prob[1]) / 2)
    np.testing.assert_allclose(out[1], ratio / ratio.sum())
    ratio = np.array([0.0, 0.5 / 0.55, 0.5 / 0.35])  # frames 1 and 2 only (memory 2)
    np.testing.assert_allclose(out[2], ratio / ratio.sum())
    np.testing.assert_array_equal(stream_contrast(prob, 0), prob)
    # causal: later frames do not change earlier rows
    changed = prob.copy()
    changed[2] = [1.0, 0.0, 0.0]
    np.testing.assert_array_equal(stream_contrast(changed, 2)[:2], out[:2])


def test_hub_place_fools_the_window_search_but_not_the_tracker() -> None:
    """The failure seen on Nordland: runs of consecutive frames vote for the same wrong place."""
    rng = np.random.default_rng(4)
    prob, true = _stream(80, 120, 1.0, 5, seed=4, decoys=0.0)
    hubs = rng.integers(0, 120, 8)
    for run, hub in enumerate(hubs):
        prob[10 * run : 10 * run + 10, hub] += 0.03  # each run of 10 frames shares one wrong peak above the true one
    prob /= prob.sum(axis=1, keepdims=True)
    settled = slice(30, None)
    v_window, _ = estimate_velocity(prob, 5, GRID)
    assert np.mean(prob.argmax(axis=1) == true) < 0.1  # single frames are nearly always wrong
    assert np.mean(v_window[settled] == 1.0) < 0.5
    v_hat, agg = track_velocity(prob, 5, GRID)
    assert np.mean(v_hat[settled] == 1.0) >= 0.95
    assert np.mean(agg[settled].argmax(axis=1) == true[settled]) >= 0.9


def test_invalid_arguments() -> None:
    prob = np.full((4, 5), 0.2)
    for span in (0, -1, 2.5, True):
        with pytest.raises(ValueError, match="span"):
            track_velocity(prob, 2, GRID, span=span)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="candidates"):
        track_velocity(prob, 2, [])
    with pytest.raises(ValueError, match="candidates"):
        window_scores(prob, 2, [1.0, np.nan])
    with pytest.raises(ValueError, match="window size"):
        window_scores(prob, 0, GRID)
    for memory in (-1, 1.5, True):
        with pytest.raises(ValueError, match="memory"):
            stream_contrast(prob, memory)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("velocity", "start"),
    [(1.0, 3), (2.0, 2), (-1.0, 75), (0.5, 10.2)],
)
def test_smoothing_recovers_a_known_velocity_from_the_first_queries(velocity: float, start: float) -> None:
    prob, true = _stream(60, 130, velocity, start, seed=3)
    v_hat, agg = smooth_velocity(prob, 5, GRID, memory=0)
    assert np.all(v_hat == velocity)  # no warm-up: the lag gives the first windows the next 9 as well
    assert np.mean(agg[4:].argmax(axis=1) == true[4:]) >= 0.95
    np.testing.assert_array_equal(agg, aggregate(prob, 5, v_hat))
    # the causal tracker on the same stream needs a warm-up
    v_track, _ = track_velocity(prob, 5, GRID, memory=0)
    assert np.mean(v_track[:10] == velocity) < 1.0


def test_smoothing_handles_dropped_frames_and_reversal() -> None:
    kept = np.sort(np.random.default_rng(7).choice(100, 60, replace=False)).astype(float)
    prob, true = _stream(60, 110, 1.0, 4, seed=8, positions=kept)
    v_hat, agg = smooth_velocity(prob, 5, GRID, frame_positions=kept)
    assert np.all(v_hat == 1.0)
    assert np.mean(agg[4:].argmax(axis=1) == true[4:]) >= 0.95
    # the same frames seen in reverse (the stream's own positions count up again)
    reverse_positions = kept[-1] - kept[::-1]
    v_rev, agg_rev = smooth_velocity(prob[::-1], 5, GRID, frame_positions=reverse_positions)
    assert np.all(v_rev == -1.0)
    assert np.mean(agg_rev[4:].argmax(axis=1) == true[::-1][4:]) >= 0.95


def test_smoothing_is_the_centre_of_the_best_of_the_lagged_sum() -> None:
    prob, _ = _stream(30, 40, 1.0, 2, seed=5, decoys=0.9)
    span, lag, length, memory = 4, 3, 7, 12
    e = window_scores(stream_contrast(prob, memory, lag), length, GRID, nearest=True)
    totals = np.array([e[max(0, j - span + 1) : j + lag + 1].sum(axis=0) for j in range(30)])
    v_hat, agg = smooth_velocity(prob, 3, GRID, span, lag=lag, length=length, memory=memory)
    np.testing.assert_allclose(lagged_sum(e, span, lag), totals, rtol=1e-12)
    np.testing.assert_array_equal(v_hat, centre_of_best(lagged_sum(e, span, lag), GRID))
    np.testing.assert_array_equal(agg, aggregate(prob, 3, v_hat))
    # defaults: lag 2k - 1, trajectories of 3k frames
    default = smooth_velocity(prob, 3, GRID, span, memory=memory)[0]
    np.testing.assert_array_equal(default, smooth_velocity(prob, 3, GRID, span, lag=5, length=9, memory=memory)[0])


def test_smoothing_waits_exactly_lag_frames() -> None:
    prob, _ = _stream(40, 60, 1.0, 2, seed=6)
    lag = 6
    v_hat, agg = smooth_velocity(prob, 5, GRID, 8, lag=lag)
    changed = prob.copy()
    changed[25:] = np.random.default_rng(0).random((15, 60))
    v_changed, agg_changed = smooth_velocity(changed, 5, GRID, 8, lag=lag)
    np.testing.assert_array_equal(v_changed[: 25 - lag], v_hat[: 25 - lag])
    np.testing.assert_array_equal(agg_changed[: 25 - lag], agg[: 25 - lag])
    # lag 0 is causal
    v0, _ = smooth_velocity(prob, 5, GRID, 8, lag=0)
    np.testing.assert_array_equal(smooth_velocity(changed, 5, GRID, 8, lag=0)[0][:25], v0[:25])


def test_lagged_sum_by_hand() -> None:
    e = np.arange(5.0)[:, None] * np.array([[1.0, 10.0]])
    np.testing.assert_array_equal(lagged_sum(e, 2, 0)[:, 0], [0, 1, 3, 5, 7])
    np.testing.assert_array_equal(lagged_sum(e, 1, 2)[:, 0], [3, 6, 9, 7, 4])
    np.testing.assert_array_equal(lagged_sum(e, 2, 1)[:, 1], [10, 30, 60, 90, 70])


def test_centre_of_best_by_hand() -> None:
    cands = np.array([0.9, 0.95, 1.0, 1.05, 1.1])
    totals = np.array([[0, 1, 1, 1, 0], [0, 0, 0, 2, 2], [3, 0, 0, 0, 0], [1, 1, 1, 1, 1]], dtype=float)
    np.testing.assert_allclose(centre_of_best(totals, cands), [1.0, 1.075, 0.9, 1.0])


def test_nearest_shifts_round_the_displacement() -> None:
    prob, _ = _stream(12, 30, 1.0, 2, seed=2)
    # over 4 frames 0.95, 1.0 and 1.05 all round to shifts of 0, 1, 2, 3 places: identical scores
    e = window_scores(prob, 4, [0.95, 1.0, 1.05], nearest=True)
    np.testing.assert_array_equal(e[:, 0], e[:, 1])
    np.testing.assert_array_equal(e[:, 2], e[:, 1])
    # at an integral velocity nearest and interpolated shifts agree
    np.testing.assert_array_equal(window_scores(prob, 4, [1.0, 2.0], nearest=True), window_scores(prob, 4, [1.0, 2.0]))


def test_stream_contrast_with_a_lag_takes_the_next_frames() -> None:
    prob = np.array([[0.5, 0.5, 0.0], [0.2, 0.6, 0.2], [0.0, 0.5, 0.5]])
    out = stream_contrast(prob, 2, 1)
    ratio = prob[0] / ((prob[0] + prob[1]) / 2)
    np.testing.assert_allclose(out[0], ratio / ratio.sum())
    ratio = prob[1] / prob.mean(axis=0)  # frames 0, 1 (memory 2) and 2 (lag 1)
    np.testing.assert_allclose(out[1], ratio / ratio.sum())
    np.testing.assert_array_equal(stream_contrast(prob, 2, 0), stream_contrast(prob, 2))


def test_invalid_smoothing_arguments() -> None:
    prob = np.full((4, 5), 0.2)
    for lag in (-1, 1.5, True):
        with pytest.raises(ValueError, match="lag"):
            smooth_velocity(prob, 2, GRID, lag=lag)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="lag"):
            stream_contrast(prob, 2, lag)  # type: ignore[arg-type]
    for span in (0, 2.5):
        with pytest.raises(ValueError, match="span"):
            smooth_velocity(prob, 2, GRID, span=span)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="candidates"):
        smooth_velocity(prob, 2, [])
