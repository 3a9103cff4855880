"""Velocity-compensated sequence aggregation over a sliding window (paper Sec. V).

Input: one distribution per query frame over the reference places (``prob``, shape ``(n_queries, n_places)``, places in
reference order, i.e. consecutive places along the route), in the order the robot saw the frames. The window of query
``j`` is the ``k`` most recent frames ``j-k+1 .. j`` in stream order (fewer at the start of the stream). Frame ``m`` of
the window lies ``d = t_j - t_m >= 0`` frame units in the past (``t`` = ``frame_positions``: frame index, timestamp or
odometry, whatever the robot knows at query time), so at ``v`` places per frame unit the robot has since moved ``v * d``
places forward; its distribution is shifted by that much before combining:

.. math:: \\tilde P_m(l) = P_m(l - v d)

evaluated with linear interpolation between the two neighbouring places (no rounding). Windows come from the stream
order and ``frame_positions`` only, never from ground-truth labels (unlike the paper's code, field notes Sec. 1).
"""

from __future__ import annotations

from typing import Final

import numpy as np

from vprsnn_export.arguments import real_array
from vprsnn_export.errors import InvalidValueError

from .assignment import finite_array, finite_matrix
from .rules import DEFAULT_RULE, RULES

#: Upper bound on the elements of one (chunk, k, n_places) working array. About
#: ten such float64/intp arrays are alive at once, so the peak is ~320 MB.
_MAX_ELEMENTS: Final[int] = 4_000_000
#: The velocity searches' defaults (:class:`~vprsnn_export.readout.sequence.SequenceOptions` takes them from here):
#: windows whose scores are summed, and recent frames whose mean is divided out.
DEFAULT_SPAN: Final[int] = 10
DEFAULT_MEMORY: Final[int] = 50


def _prob2d(prob: np.ndarray) -> np.ndarray:
    p = finite_matrix("prob", prob)
    if np.any(p < 0):
        raise InvalidValueError("prob contains negative values")
    return p


def _velocities(velocity: float | np.ndarray, n: int) -> np.ndarray:
    if np.asarray(velocity).dtype.kind == "b":
        raise InvalidValueError(f"velocity must be places per frame (a number or one per query), got {velocity!r}")
    v = real_array("velocity", velocity)
    v = np.full(n, float(v)) if v.ndim == 0 else v
    if v.shape != (n,):
        raise InvalidValueError(f"velocity must be a float or have shape ({n},), got {v.shape}")
    return finite_array("velocity", v)


def count_at_least(name: str, value: int, low: int) -> int:
    """``value`` as an int when it is an integer (not a bool) >= ``low``; InvalidValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise InvalidValueError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


def _check_args(k: int, rule: str, eps: float) -> int:
    k = count_at_least("window size k", k, 1)
    RULES.get(rule)  # InvalidValueError naming the registered rules
    if not (np.isfinite(eps) and eps > 0):
        raise InvalidValueError(f"eps must be a finite value > 0, got {eps}")
    return k


def _checked(
    prob: np.ndarray, k: int, rule: str, eps: float, frame_positions: np.ndarray | None
) -> tuple[np.ndarray, int, np.ndarray]:
    """The checked ``prob``, the window length that matters (:func:`_window`) and the frame positions."""
    p = _prob2d(prob)
    n = p.shape[0]
    k = _window(_check_args(k, rule, eps), n)
    if frame_positions is None:
        return p, k, np.arange(n, dtype=np.float64)
    t = real_array("frame_positions", frame_positions)
    if t.shape != (n,):
        raise InvalidValueError(f"frame_positions must have shape ({n},), got {t.shape}")
    if np.any(np.diff(finite_array("frame_positions", t)) < 0):
        raise InvalidValueError("frame_positions must be non-decreasing in stream order")
    return p, k, t


def _window(k: int, n_queries: int) -> int:
    """The window length that matters: any k > max(N, 2) acts as max(N, 2) (W_j never reaches before frame 0)."""
    return k if k == 1 else min(k, max(n_queries, 2))


def shift_window(
    prob: np.ndarray, queries: np.ndarray, k: int, velocity: np.ndarray, frame_positions: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Shifted window distributions ``(len(queries), k, n_places)``; offset ``o`` holds frame ``m = j - o``:

    .. math:: \\tilde P_{j,o}(l) = (1 - f) P_m(\\lfloor x \\rfloor) + f P_m(\\lfloor x \\rfloor + 1),
              \\quad x = l - v_j (t_j - t_m), \\quad f = x - \\lfloor x \\rfloor

    and 0 where ``x`` lies outside ``[0, n_places - 1]``. Returns ``(shifted, valid)``; ``valid[c, o]`` is False
    (and the row 0) where ``m < 0``, before the stream's start. Inputs must already be validated float64.
    """
    return _shift_rows(prob, queries, k, velocity[queries], frame_positions)


def _shift_rows(
    prob: np.ndarray,
    queries: np.ndarray,
    k: int,
    row_velocity: np.ndarray,
    frame_positions: np.ndarray,
    nearest: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`shift_window` with one velocity per row (a query may stand in several rows, as in
    :func:`window_scores`); ``nearest`` rounds each displacement to whole places (half to even), so ``f = 0``."""
    n_places = prob.shape[1]
    frames, valid, displacement, shift = _window_frames(queries, k, row_velocity, frame_positions, n_places, nearest)
    if shift is not None:  # every row's offset o moves by the same whole places d_o: P_{j-o}(l - d_o) by slicing
        shifted = np.zeros((len(frames), k, n_places))  # (the same numbers as the interpolation at f = 0)
        for o, d in enumerate(shift.tolist()):  # k offsets, each a slice over every row and place
            if abs(d) < n_places:
                source = prob[frames[:, o]]
                if d >= 0:
                    shifted[:, o, d:] = source[:, : n_places - d]
                else:
                    shifted[:, o, :d] = source[:, -d:]
        shifted[~valid] = 0.0
        return shifted, valid
    x = np.arange(n_places, dtype=np.float64)[None, None, :] - displacement[:, :, None]  # (C, k, P)
    x0 = np.floor(x)
    frac = x - x0
    inside = (x >= 0) & (x <= n_places - 1) & valid[:, :, None]
    i0 = np.clip(x0, 0, n_places - 1).astype(np.intp)
    i1 = np.clip(x0 + 1, 0, n_places - 1).astype(np.intp)
    rows = frames[:, :, None]
    # frac == 0 exactly for an integral shift, so the right neighbour drops out
    shifted = (1.0 - frac) * prob[rows, i0] + frac * prob[rows, i1]
    shifted[~inside] = 0.0
    return shifted, valid


def _window_frames(
    queries: np.ndarray,
    k: int,
    row_velocity: np.ndarray,
    frame_positions: np.ndarray,
    n_places: int,
    nearest: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Each row's window frames (C, k) (0 before the stream), whether they exist, their displacements
    :math:`v_j (t_j - t_m)` and the whole-place shift per offset when all rows share it (else None)."""
    frames = queries[:, None] - np.arange(k)[None, :]  # (C, k)
    valid = frames >= 0
    frames_safe = np.where(valid, frames, 0)
    displacement = row_velocity[:, None] * (frame_positions[queries][:, None] - frame_positions[frames_safe])
    if nearest:
        displacement = np.rint(displacement)
    common = np.where(valid[-1], displacement[-1], 0.0)  # the last row reaches every offset any row reaches
    whole = np.all((displacement == common) | ~valid) and np.all(common == np.rint(common))
    return frames_safe, valid, displacement, np.clip(common, -n_places, n_places).astype(np.intp) if whole else None


def _summed_terms(
    terms: np.ndarray, queries: np.ndarray, valid: np.ndarray, shift: np.ndarray, outside: float
) -> np.ndarray:
    r""":math:`A_j(l) = \sum_o \text{term}(P_{j-o})(l - d_o)` for the consecutive ``queries`` from each frame's
    ``terms`` computed once, ``outside`` (the term of 0) beyond the map: the same numbers as ``combine``."""
    n_places = terms.shape[1]
    total = terms[queries]  # offset 0: the query frame itself, never shifted (d_0 = 0)
    for o, d in enumerate(shift.tolist()[1:], start=1):
        ok = valid[:, o]
        rows = slice(None) if ok.all() else np.flatnonzero(ok)
        frames = queries[rows] - o
        source = terms[frames[0] : frames[-1] + 1] if len(frames) else terms[:0]
        target = total[rows]  # a view when every row has this frame, else a copy written back below
        if abs(d) >= n_places:
            target += outside
        elif d >= 0:
            target[:, :d] += outside
            target[:, d:] += source[:, : n_places - d]
        else:
            target[:, d:] += outside
            target[:, :d] += source[:, -d:]
        if not ok.all():
            total[rows] = target
            total[~ok] += outside * 0.0  # the 0 that combine adds for a missing frame (so -0.0 becomes 0.0 alike)
    return total


def aggregate(
    prob: np.ndarray,
    k: int,
    velocity: float | np.ndarray,
    rule: str = DEFAULT_RULE,
    frame_positions: np.ndarray | None = None,
    eps: float = 1e-6,
) -> np.ndarray:
    """Velocity-compensated aggregation of the k most recent frames, shape ``(n_queries, n_places)``.

    For query ``j`` with window ``W_j = {max(0, j-k+1), ..., j}`` (stream order):

    .. math::
        \\tilde P_m(l) = P_m\\big(l - v_j (t_j - t_m)\\big) \\quad
            (\\text{linear interpolation; } 0 \\text{ outside } [0, N_{places}-1])

        \\text{product:}\\; A_j(l) = \\sum_{m \\in W_j} \\log(\\tilde P_m(l) + \\varepsilon), \\quad
            \\hat P_j(l) = \\frac{e^{A_j(l)}}{\\sum_{l'} e^{A_j(l')}}

        \\text{sum:}\\; A_j(l) = \\sum_{m \\in W_j} \\tilde P_m(l), \\quad
            \\hat P_j(l) = \\frac{A_j(l)}{\\sum_{l'} A_j(l')}

    ``velocity``: places per frame unit, a float or one per query (negative: against the reference order).
    ``frame_positions`` (``t``): non-decreasing, default ``arange(n_queries)``. ``eps`` (product rule) floors
    every factor so one frame cannot veto a place. A sum-rule window 0 everywhere gives the uniform distribution;
    ``k == 1`` returns a float64 copy of ``prob``; an empty stream is an InvalidValueError.
    """
    if _prob2d(prob).shape[0] == 0:
        raise InvalidValueError("prob holds no query (shape (0, places)): there is nothing to aggregate")
    return _aggregate_scored(prob, k, velocity, rule, frame_positions, eps)[0]


def _aggregate_scored(
    prob: np.ndarray, k: int, velocity: float | np.ndarray, rule: str, frame_positions: np.ndarray | None, eps: float
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`aggregate` plus each window's score max_l A_j(l) of the un-normalised aggregate (the registered rule's
    ``combine``, :data:`RULES`), which the velocity search maximises."""
    p, k, t = _checked(prob, k, rule, eps, frame_positions)
    n_queries, n_places = p.shape
    v = _velocities(velocity, n_queries)
    if k == 1:
        return p.copy(), p.max(axis=1)
    out = np.empty_like(p)
    score = np.empty(n_queries)
    combiner, terms = RULES.get(rule), None
    outside = combiner.zero_term(eps)  # a place beyond the map
    chunk = max(1, _MAX_ELEMENTS // n_places)
    for start in range(0, n_queries, chunk):
        queries = np.arange(start, min(start + chunk, n_queries))
        _, valid, _, shift = _window_frames(queries, k, v[queries], t, n_places)
        if shift is not None:  # whole places: every frame's term once, shifted
            terms = combiner.term(p, eps) if terms is None else terms
            out[queries], score[queries] = combiner.finish(_summed_terms(terms, queries, valid, shift, outside))
            continue
        for part in np.array_split(queries, -(-len(queries) * k // chunk)):  # the (rows, k, places) window
            shifted, valid = shift_window(p, part, k, v, t)
            out[part], score[part] = combiner.combine(shifted, valid, eps)
    return out, score


def aggregate_newest(
    prob: np.ndarray, k: int, velocity: float, rule: str = DEFAULT_RULE, eps: float = 1e-6
) -> np.ndarray:
    """The newest frame's aggregate alone, ``aggregate(prob, k, velocity, rule)[-1:]`` (the same numbers) at a
    k-th of its cost: a stream needs no other row. ``prob``: the recent frames in stream order, newest last."""
    n = len(prob)
    shifted, valid = shift_window(prob, np.array([n - 1]), _window(k, n), np.full(n, velocity), np.arange(float(n)))
    return RULES.get(rule).combine(shifted, valid, eps)[0]


def frame_term(row: np.ndarray, rule: str = DEFAULT_RULE, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """One frame's term row of the rule's sum (the product's :math:`\\log(P(l) + \\varepsilon)`) and its support
    :math:`\\{l : P(l) \\ne 0\\}`, kept by a stream as the frame comes (:func:`aggregate_newest_on_support`):
    elsewhere the term is the term of 0, so it is taken on the support alone."""
    combiner = RULES.get(rule)
    support = np.flatnonzero(row)
    term = np.full(row.shape, combiner.zero_term(eps))
    term[support] = combiner.term(row[support], eps)
    return term, support


def aggregate_newest_on_support(
    terms: list[np.ndarray], supports: list[np.ndarray], velocity: float, rule: str = DEFAULT_RULE, eps: float = 1e-6
) -> np.ndarray | None:
    r""":func:`aggregate_newest` of the recent frames (oldest first) from their :func:`frame_term` rows and supports,
    the same numbers, at the cost of the places some shifted frame supports (``U``; None when the frames are not
    shifted by whole places ``d_o``): elsewhere every term is the term of 0, ``c``.

    .. math:: A(l) = \sum_o t_{j-o}(l - d_o) \; (l \in U), \quad A(l) = c + \dots + c \; (l \notin U), \quad
              U = \bigcup_o (S_{j-o} + d_o)

    summed in :func:`aggregate`'s order (offset 0 first), then the rule's ``finish`` over every place
    (:meth:`~.rules.AggregationRule.finish_row`)."""
    n, n_places = len(terms), len(terms[-1])
    _, _, _, shift = _window_frames(np.array([n - 1]), n, np.array([velocity]), np.arange(float(n)), n_places)
    if shift is None:
        return None
    combiner = RULES.get(rule)
    outside = combiner.zero_term(eps)  # every unsupported place's term, and beyond the map
    offsets = list(enumerate(shift.tolist()))
    union = np.unique(np.concatenate([supports[n - 1 - o] + d for o, d in offsets]))
    union = union[(union >= 0) & (union < n_places)]
    total, rest = terms[n - 1][union], np.array([outside])
    for o, d in offsets[1:]:
        source = union - d
        inside = (source >= 0) & (source < n_places)
        total += np.where(inside, terms[n - 1 - o][np.where(inside, source, 0)], outside)
        rest += outside
    return combiner.finish_row(total, union, float(rest[0]), n_places)


def window_scores(
    prob: np.ndarray,
    k: int,
    candidates: np.ndarray,
    rule: str = DEFAULT_RULE,
    frame_positions: np.ndarray | None = None,
    eps: float = 1e-6,
    *,
    nearest: bool = False,
    windows: np.ndarray | None = None,
) -> np.ndarray:
    """How well each window fits each candidate velocity, shape ``(n_queries, n_candidates)``.

    .. math:: e_j(v) = \\max_l A_j^{(v)}(l)

    where ``A^{(v)}`` is :func:`aggregate`'s un-normalised aggregate at velocity v; with ``k == 1`` every
    candidate scores ``max_l P_j(l)``. ``nearest=True`` shifts by whole places, as SeqSLAM does (interpolation
    blurs a frame, which the concave log of the product rule rewards). ``windows``: the stream indices to score
    (default all), rows in that order.
    """
    cands = _candidates(candidates)
    p, k, t = _checked(prob, k, rule, eps, frame_positions)
    n_queries, n_places = p.shape
    scored = np.arange(n_queries) if windows is None else np.asarray(windows, dtype=np.intp)
    if k == 1:
        return np.repeat(p[scored].max(axis=1)[:, None], cands.size, axis=1)
    rows_query = np.repeat(scored, cands.size)
    rows_velocity = np.tile(cands, scored.size)
    scores = np.empty(rows_query.size)
    chunk = max(1, _MAX_ELEMENTS // (k * n_places))
    for start in range(0, rows_query.size, chunk):
        rows = slice(start, start + chunk)
        shifted, valid = _shift_rows(p, rows_query[rows], k, rows_velocity[rows], t, nearest)
        scores[rows] = RULES.get(rule).combine(shifted, valid, eps)[1]
    return scores.reshape(scored.size, cands.size)


def _candidates(candidates: np.ndarray) -> np.ndarray:
    cands = real_array("candidates", candidates).ravel()
    if cands.size == 0:
        raise InvalidValueError("candidates must contain at least one velocity")
    return finite_array("candidates", cands)


def estimate_velocity(
    prob: np.ndarray,
    k: int,
    candidates: np.ndarray,
    rule: str = DEFAULT_RULE,
    frame_positions: np.ndarray | None = None,
    eps: float = 1e-6,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-window velocity search over a candidate grid; returns ``(velocity (Q,), aggregated (Q, places))``.

    .. math:: \\hat v_j = \\arg\\max_{v \\in \\mathcal{V}} e_j(v) = \\arg\\max_{v} \\max_l A_j^{(v)}(l)

    (:func:`window_scores`; ties: the first candidate). Each window decides alone (see :func:`track_velocity`).
    """
    return track_velocity(prob, k, candidates, 1, rule, frame_positions, eps, length=k, memory=0)


def stream_contrast(prob: np.ndarray, memory: int, lag: int = 0) -> np.ndarray:
    """Each frame divided by the mean of the ``memory`` most recent frames, shape ``(n_queries, n_places)``.

    .. math::
        B_j(l) = \\frac{1}{j_1 - j_0 + 1} \\sum_{i=j_0}^{j_1} P_i(l), \\quad
            j_0 = \\max(0, j - M + 1), \\; j_1 = \\min(n - 1, j + L), \\qquad
        Q_j(l) = \\frac{P_j(l) / B_j(l)}{\\sum_{l'} P_j(l') / B_j(l')}

    (0 where ``B_j(l) = 0``; a row 0 everywhere stays 0): a "hub" place that consecutive frames all vote for is
    discounted, the moving true place is not. ``lag`` L = 0 is causal; ``memory == 0`` returns a float64 copy.
    """
    p = _prob2d(prob)
    memory, lag = count_at_least("background memory", memory, 0), count_at_least("velocity lag", lag, 0)
    if memory == 0:
        return p.copy()
    cumulative = np.concatenate([np.zeros((1, p.shape[1])), np.cumsum(p, axis=0)])
    j = np.arange(p.shape[0])
    first = np.maximum(0, j - memory + 1)
    last = np.minimum(p.shape[0] - 1, j + lag)
    background = (cumulative[last + 1] - cumulative[first]) / (last + 1 - first)[:, None]
    ratio = np.divide(p, background, out=np.zeros_like(p), where=background > 0)
    total = ratio.sum(axis=1, keepdims=True)
    return np.divide(ratio, total, out=np.zeros_like(ratio), where=total > 0)


def lagged_sum(scores: np.ndarray, span: int, lag: int) -> np.ndarray:
    """Sum of the rows from ``span`` - 1 before to ``lag`` after each row, shape of ``scores``.

    .. math:: E_j = \\sum_{i=\\max(0,\\, j-S+1)}^{\\min(n-1,\\, j+L)} e_i

    ``lag`` L = 0 is the causal sum over the S most recent rows.
    """
    padded = np.concatenate([np.zeros((span - 1,) + scores.shape[1:]), scores, np.zeros((lag,) + scores.shape[1:])])
    return np.lib.stride_tricks.sliding_window_view(padded, span + lag, axis=0).sum(axis=-1)


def centre_of_best(totals: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """Per row, the mean of the candidates that reach the row's maximum, shape ``(n_rows,)``.

    .. math:: \\hat v_j = \\operatorname{mean} \\{ v \\in \\mathcal{V} : E_j(v) = \\max_{v'} E_j(v') \\}

    Velocities that round to the same whole-place shifts tie exactly; their centre is unbiased, the first is not.
    """
    best = totals == totals.max(axis=1, keepdims=True)
    return (best * candidates[None, :]).sum(axis=1) / best.sum(axis=1)


def track_velocity(
    prob: np.ndarray,
    k: int,
    candidates: np.ndarray,
    span: int = DEFAULT_SPAN,
    rule: str = DEFAULT_RULE,
    frame_positions: np.ndarray | None = None,
    eps: float = 1e-6,
    *,
    length: int | None = None,
    memory: int = DEFAULT_MEMORY,
) -> tuple[np.ndarray, np.ndarray]:
    """Velocity tracked over the query stream; returns ``(velocity, aggregated)``.

    Three steps, all causal (query ``j`` uses frames ``0 .. j`` only):

    .. math::
        Q = \\text{stream\\_contrast}(P, M), \\qquad
        E_j(v) = \\sum_{i=\\max(0,\\, j-S+1)}^{j} e_i^{(Q, L)}(v), \\qquad
        \\hat v_j = \\arg\\max_{v \\in \\mathcal{V}} E_j(v), \\qquad
        \\hat P_j = \\text{aggregate}(P, k, \\hat v)_j

    1. :func:`stream_contrast` divides out the places the last ``memory`` (M) frames all vote for (else
       frames stuck on one wrong place make velocity 0 look best).
    2. ``e_i^{(Q, L)}(v)``: :func:`window_scores` of Q over trajectories of ``length`` (L, default 2k) frames.
    3. The scores of the ``span`` (S) most recent windows are summed: the right velocity lines up every window.

    The decision aggregates the unchanged ``prob`` over k frames at the chosen velocity (ties: the first
    candidate). ``span=1, length=k, memory=0`` is :func:`estimate_velocity`.
    """
    span = count_at_least("velocity span", span, 1)
    k = _check_args(k, rule, eps)
    cands = _candidates(candidates)
    length = 2 * k if length is None else length
    scores = window_scores(stream_contrast(prob, memory), length, cands, rule, frame_positions, eps)
    velocity = cands[np.argmax(lagged_sum(scores, span, 0), axis=1)]
    return velocity, aggregate(prob, k, velocity, rule, frame_positions, eps)


def smooth_velocity(
    prob: np.ndarray,
    k: int,
    candidates: np.ndarray,
    span: int = DEFAULT_SPAN,
    rule: str = DEFAULT_RULE,
    frame_positions: np.ndarray | None = None,
    eps: float = 1e-6,
    *,
    lag: int | None = None,
    length: int | None = None,
    memory: int = DEFAULT_MEMORY,
) -> tuple[np.ndarray, np.ndarray]:
    """Velocity smoothed over the recent and the next ``lag`` windows (fixed lag); returns ``(velocity, aggregated)``.

    .. math::
        Q = \\text{stream\\_contrast}(P, M, L), \\qquad
        E_j(v) = \\sum_{i=\\max(0,\\, j-S+1)}^{\\min(n-1,\\, j+L)} e_i^{(Q, T, \\text{nearest})}(v),

        \\hat v_j = \\operatorname{mean} \\{ v : E_j(v) = \\max_{v'} E_j(v') \\}, \\qquad
        \\hat P_j = \\text{aggregate}(P, k, \\hat v)_j

    :func:`track_velocity` with three changes, for its warm-up:

    1. **Fixed lag** L (default ``2k - 1``): query ``j``'s velocity also sums the next L windows' scores
       (:func:`lagged_sum`) and its background takes the next L frames; the decision still aggregates frames
       ``j-k+1 .. j``. ``lag=0`` is causal.
    2. **Trajectories through whole places** (``nearest=True``) of ``length`` T (default 3k) frames.
    3. **The centre of the tied best velocities** (:func:`centre_of_best`).
    """
    span = count_at_least("velocity span", span, 1)
    k = _check_args(k, rule, eps)
    lag = count_at_least("velocity lag", 2 * k - 1 if lag is None else lag, 0)
    cands = _candidates(candidates)
    length = 3 * k if length is None else length
    scores = window_scores(stream_contrast(prob, memory, lag), length, cands, rule, frame_positions, eps, nearest=True)
    velocity = centre_of_best(lagged_sum(scores, span, lag), cands)
    return velocity, aggregate(prob, k, velocity, rule, frame_positions, eps)
