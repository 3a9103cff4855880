"""Velocity-compensated sequence aggregation (honest version: no ground truth)."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.readout import aggregation
from vprsnn_export.readout.aggregation import (
    aggregate,
    aggregate_newest,
    aggregate_newest_on_support,
    estimate_velocity,
    frame_term,
    shift_window,
)
from vprsnn_export.readout.rules import RULES


def _diagonal(
    n_queries: int,
    n_places: int,
    velocity: float,
    start: float,
    seed: int,
    positions: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Noisy per-frame distributions of a constant-velocity traversal.

    Returns (prob, true place index). A moderate Gaussian bump sits at the
    continuous position (so fractional velocities are representable);
    on about half the frames a stronger decoy peak sits at a random place, so
    single frames are often wrong.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n_queries, dtype=float) if positions is None else positions
    pos = start + velocity * t  # continuous position along the route
    true = np.rint(pos).astype(int)
    places = np.arange(n_places, dtype=float)
    bump = np.exp(-0.5 * ((places[None, :] - pos[:, None]) / 0.7) ** 2)
    prob = rng.random((n_queries, n_places)) * 0.3 + 0.6 * bump
    decoy = rng.random(n_queries) < 0.5
    where = rng.integers(0, n_places, n_queries)
    prob[np.flatnonzero(decoy), where[decoy]] += 1.0
    return prob / prob.sum(axis=1, keepdims=True), true


def test_k1_is_identity() -> None:
    prob, _ = _diagonal(20, 30, 1.0, 2, seed=1)
    for rule in ("product", "sum"):
        out = aggregate(prob, 1, 1.37, rule)
        assert np.array_equal(out, prob) and out is not prob


def test_hand_computed_fractional_shift() -> None:
    prob = np.array([[0.0, 0.2, 0.6, 0.2, 0.0], [0.1, 0.2, 0.3, 0.2, 0.2]])
    t = np.array([0.0, 1.0])
    shifted, valid = shift_window(prob, np.array([1]), 2, np.array([0.5, 0.5]), t)
    assert valid.tolist() == [[True, True]]
    np.testing.assert_array_equal(shifted[0, 0], prob[1])  # d = 0: unshifted
    # d = 1, v = 0.5: P_0(l - 0.5) = mean of places l-1 and l; position -0.5 is off the map
    np.testing.assert_allclose(shifted[0, 1], [0.0, 0.1, 0.4, 0.4, 0.1])
    # the sum rule adds and L1-normalises
    out = aggregate(prob, 2, 0.5, "sum", t)
    expected = shifted[0].sum(axis=0)
    np.testing.assert_allclose(out[1], expected / expected.sum())
    # the product rule multiplies (eps-floored) and normalises
    out = aggregate(prob, 2, 0.5, "product", t, eps=1e-6)
    expected = (shifted[0, 0] + 1e-6) * (shifted[0, 1] + 1e-6)
    np.testing.assert_allclose(out[1], expected / expected.sum())
    # first query: window of one frame only
    np.testing.assert_allclose(out[0], (prob[0] + 1e-6) / (prob[0] + 1e-6).sum())


def test_integral_shift_is_exact_and_negative_velocity() -> None:
    prob = np.random.default_rng(3).random((4, 9))
    shifted, valid = shift_window(prob, np.array([3]), 4, np.full(4, 2.0), np.arange(4.0))
    for o in range(4):
        expected = np.zeros(9)
        expected[2 * o :] = prob[3 - o, : 9 - 2 * o]
        assert np.array_equal(shifted[0, o], expected)
    shifted, _ = shift_window(prob, np.array([3]), 2, np.full(4, -1.0), np.arange(4.0))
    expected = np.zeros(9)
    expected[:-1] = prob[2, 1:]
    assert np.array_equal(shifted[0, 1], expected)
    # before the start of the stream: invalid rows, zero
    shifted, valid = shift_window(prob, np.array([1]), 3, np.ones(4), np.arange(4.0))
    assert valid.tolist() == [[True, True, False]]
    assert np.all(shifted[0, 2] == 0)


@pytest.mark.parametrize("rule", ["product", "sum"])
def test_noisy_diagonal_becomes_correct_at_true_velocity(rule: str) -> None:
    k = 5
    prob, true = _diagonal(60, 80, 1.0, 5, seed=7)
    single = np.mean(prob.argmax(axis=1) == true)
    agg = aggregate(prob, k, 1.0, rule)
    full = np.arange(k - 1, 60)
    assert single < 0.75
    assert np.all(agg[full].argmax(axis=1) == true[full])
    np.testing.assert_allclose(agg.sum(axis=1), 1.0)


def test_reversed_traversal_and_dropped_frames() -> None:
    # reversed: the robot drives against the reference order
    prob, true = _diagonal(40, 60, -1.0, 50, seed=11)
    agg = aggregate(prob, 5, -1.0)
    assert np.all(agg[4:].argmax(axis=1) == true[4:])
    # dropped frames: the known frame positions skip, the stream order does not
    keep = np.sort(np.random.default_rng(5).choice(80, 50, replace=False)).astype(float)
    prob, true = _diagonal(50, 90, 1.0, 3, seed=13, positions=keep)
    agg = aggregate(prob, 5, 1.0, frame_positions=keep)
    assert np.all(agg[4:].argmax(axis=1) == true[4:])
    # ignoring the positions (pretending no drop) is worse
    naive = aggregate(prob, 5, 1.0)
    assert np.mean(naive[4:].argmax(axis=1) == true[4:]) < 1.0


def test_ten_percent_velocity_error_changes_result() -> None:
    prob, _ = _diagonal(30, 50, 1.0, 2, seed=2)
    k = 5
    d = np.arange(k)
    # the paper's code rounds each shift: at k=5 a 10 % error is invisible
    assert np.array_equal(np.rint(1.1 * d), np.rint(1.0 * d))
    assert np.array_equal(np.rint(0.9 * d), np.rint(1.0 * d))
    base = aggregate(prob, k, 1.0)
    for v in (0.9, 1.1):
        other = aggregate(prob, k, v)
        assert np.max(np.abs(other[k - 1 :] - base[k - 1 :])) > 1e-3


def test_velocity_estimation_recovers_true_velocity() -> None:
    candidates = np.round(np.arange(0.5, 3.01, 0.25), 2)
    full = slice(4, None)
    v_true = 2.0
    prob, true = _diagonal(60, 140, v_true, 2, seed=21)
    single = np.mean(prob.argmax(axis=1) == true)
    v_hat, agg = estimate_velocity(prob, 5, candidates)
    assert np.mean(v_hat[full] == v_true) >= 0.9
    assert np.mean(agg[full].argmax(axis=1) == true[full]) >= 0.95 > single
    assert set(np.unique(v_hat)) <= set(candidates.tolist())
    # the returned distributions are those of the chosen velocity
    for c in np.unique(v_hat):
        rows = v_hat == c
        np.testing.assert_allclose(agg[rows], aggregate(prob, 5, float(c))[rows])
    # a fractional velocity: the peak criterion prefers grid-aligned windows, so
    # single queries may pick a neighbouring candidate, but the place stays within 1
    prob, true = _diagonal(60, 140, 1.5, 2, seed=21)
    v_hat, agg = estimate_velocity(prob, 5, candidates)
    assert np.median(v_hat[full]) == 1.5
    assert np.mean(np.abs(agg[full].argmax(axis=1) - true[full]) <= 1) >= 0.95


def test_per_query_velocity_and_chunking(monkeypatch: pytest.MonkeyPatch) -> None:
    prob, _ = _diagonal(25, 40, 1.0, 1, seed=4)
    v = np.linspace(0.7, 1.3, 25)
    full = aggregate(prob, 4, v, "product")
    for j in (0, 3, 12, 24):
        np.testing.assert_allclose(full[j], aggregate(prob, 4, float(v[j]))[j])
    monkeypatch.setattr(aggregation, "_MAX_ELEMENTS", 4 * 40 * 3)  # 3 queries per chunk
    np.testing.assert_array_equal(aggregate(prob, 4, v, "product"), full)


def test_no_ground_truth_in_signatures() -> None:
    allowed = {"prob", "k", "velocity", "candidates", "rule", "frame_positions", "eps"}
    for fn in (aggregate, estimate_velocity):
        params = set(inspect.signature(fn).parameters)
        assert params <= allowed, params
        for name in params:
            assert not any(w in name for w in ("label", "true", "gt", "place_id", "truth"))


def test_invalid_arguments() -> None:
    prob = np.full((3, 4), 0.25)
    with pytest.raises(ValueError):
        aggregate(prob, 0, 1.0)
    with pytest.raises(InvalidValueError, match="aggregation rule: unknown 'max'; choose from product, sum"):
        aggregate(prob, 2, 1.0, "max")
    with pytest.raises(ValueError):
        aggregate(prob, 2, 1.0, frame_positions=np.array([0.0, 2.0, 1.0]))
    with pytest.raises(ValueError):
        aggregate(prob, 2, np.ones(2))
    with pytest.raises(ValueError):
        aggregate(-prob, 2, 1.0)
    with pytest.raises(ValueError):
        estimate_velocity(prob, 2, [])
    # an all-zero sum-rule window is uniform
    out = aggregate(np.zeros((3, 4)), 2, 1.0, "sum")
    np.testing.assert_array_equal(out, np.full((3, 4), 0.25))


@pytest.mark.parametrize(
    ("frames", "k", "velocity", "rule"),
    [
        (10, 10, 1.0, "product"), (3, 5, 1.3, "product"), (7, 5, -0.7, "sum"), (2, 10, 0.5, "product"),
        (9, 5, 1.0, "product"), (6, 5, -2.0, "product"), (8, 3, 0.0, "sum"), (4, 5, 60.0, "product"),
    ],
)  # fmt: skip
def test_the_newest_aggregate_is_the_last_row_of_the_whole(frames, k, velocity, rule):
    """Bit for bit, from the rows and from the stream's terms and supports (when the shift is whole places, else
    None), on dense rows and on a search window's rows (0 outside their 8 places, at times a whole route's)."""
    rng = np.random.default_rng(frames)
    dense = rng.dirichlet(np.ones(40), frames)
    windowed = dense * (np.abs(np.arange(40)[None] - rng.integers(0, 40, (frames, 1))) < 4)
    windowed[::3] = dense[::3]  # a global frame now and then
    for prob in (dense, windowed / windowed.sum(axis=1, keepdims=True)):
        recent = prob[-min(k, frames) :]
        whole = aggregate(prob, k, velocity, rule)[-1:]
        assert aggregate_newest(recent, k, velocity, rule).tobytes() == whole.tobytes()
        terms, supports = zip(*(frame_term(row, rule) for row in recent), strict=True)
        assert all(
            t.tobytes() == RULES.get(rule).term(row, 1e-6).tobytes() for t, row in zip(terms, recent, strict=True)
        )
        newest = aggregate_newest_on_support(list(terms), list(supports), velocity, rule)
        assert (newest is None) == (velocity != round(velocity))
        assert newest is None or newest.tobytes() == whole.tobytes()


@pytest.mark.parametrize("velocity", [2.0, -1.0, 0.0, 7.0])
def test_a_whole_place_shift_is_the_interpolation_with_no_fraction(velocity):
    """The sliced path (every row moved by the same whole number of places per offset) against the formula:
    P~_{j,o}(l) = P_{j-o}(l - v o), 0 outside the map or before the stream."""
    rng = np.random.default_rng(4)
    prob = rng.random((9, 6))
    queries, k = np.arange(9), 4
    shifted, valid = shift_window(prob, queries, k, np.full(9, velocity), np.arange(9.0))
    expected = np.zeros((9, k, 6))
    for j in queries:
        for o in range(k):
            for place in range(6):
                source = place - int(velocity) * o
                if j - o >= 0 and 0 <= source < 6:
                    expected[j, o, place] = prob[j - o, source]
    assert shifted.tobytes() == expected.tobytes()
    np.testing.assert_array_equal(valid, (queries[:, None] - np.arange(k)[None, :]) >= 0)


def test_a_velocity_far_beyond_the_map_shifts_every_frame_out_without_an_overflow():
    """1e300 places per frame: every older frame lands off the map, as at 1e6; no RuntimeWarning from an integer
    cast of the displacement (it once overflowed: "invalid value encountered in cast")."""
    prob = np.random.default_rng(3).dirichlet(np.ones(30), size=12)
    with np.errstate(all="raise"):
        far = aggregate(prob, 3, 1e300)
    assert np.array_equal(far, aggregate(prob, 3, 1e6))


@pytest.mark.parametrize("rule", ["product", "sum"])
@pytest.mark.parametrize(("velocity", "k"), [(1.0, 5), (-2.0, 4), (0.0, 3), (3.0, 12), (40.0, 3), (-1.0, 30)])
def test_whole_place_windows_from_each_frames_term_once_are_the_shifted_windows_combined(rule, velocity, k):
    """aggregate's whole-place path (each frame's term once, summed in place offset by offset) against the rule
    combining the shifted (rows, k, places) window, bit for bit: at the stream's start, beyond the map, against
    the route, and over several chunks of queries."""
    prob = np.random.default_rng(int(abs(velocity)) + k).dirichlet(np.ones(30), size=25)
    prob[3, 4] = 0.0  # an exact zero: log(0 + eps)
    queries = np.arange(25)
    shifted, valid = shift_window(prob, queries, k, np.full(25, velocity), np.arange(25.0))
    expected, expected_score = aggregation.RULES.get(rule).combine(shifted, valid, 1e-6)
    got, score = aggregation._aggregate_scored(prob, k, velocity, rule, None, 1e-6)
    assert got.tobytes() == expected.tobytes() and score.tobytes() == expected_score.tobytes()
    with pytest.MonkeyPatch.context() as patch:  # 60 elements a chunk: two queries at a time
        patch.setattr(aggregation, "_MAX_ELEMENTS", 60)
        chunked, chunked_score = aggregation._aggregate_scored(prob, k, velocity, rule, None, 1e-6)
    assert chunked.tobytes() == expected.tobytes() and chunked_score.tobytes() == expected_score.tobytes()


@pytest.mark.parametrize("rule", ["product", "sum"])
@pytest.mark.parametrize("places", [0, 1, 7, 300])
def test_a_row_finished_from_its_filled_form_is_the_row_finished(rule, places):
    """Byte for byte: the rule's finish of a row that is one value at all but some places, from those places alone
    (the product's e^(fill - peak) taken once), as its finish over the whole row; the fill the peak or not."""
    rng = np.random.default_rng(places)
    where = np.sort(rng.choice(1000, places, replace=False))
    values = rng.normal(-20.0, 8.0, places)
    for fill in (-69.07755278982137, 5.0):
        row = np.full(1000, fill)
        row[where] = values
        combiner = RULES.get(rule)
        assert combiner.finish_row(values, where, fill, 1000).tobytes() == combiner.finish(row[None])[0].tobytes()
