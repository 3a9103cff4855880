"""Velocity-compensated sequence aggregation over a sliding window (paper Sec. V).

Input: one distribution per query frame over the reference places
(``prob``, shape ``(n_queries, n_places)``, places in reference order, i.e.
consecutive places along the route), in the order the robot saw the frames.
The window of query ``j`` is the ``k`` most recent frames ``j-k+1 .. j`` in
stream order (fewer at the start of the stream). Frame ``m`` of the window lies
``d = t_j - t_m >= 0`` frame units in the past (``t`` = ``frame_positions``:
frame index, timestamp or odometry, whatever the robot knows at query time),
so at ``v`` places per frame unit the robot has since moved ``v * d`` places
forward; its distribution is shifted by that much before combining:

.. math:: \\tilde P_m(l) = P_m(l - v d)

evaluated with linear interpolation between the two neighbouring places (no
rounding). Windows are built from the stream order and ``frame_positions``
only -- never from ground-truth labels (unlike the paper's code, field notes
Sec. 1, which cuts windows where the true labels stop being consecutive).
"""

from __future__ import annotations

from typing import Final

import numpy as np

RULES: Final[tuple[str, ...]] = ("product", "sum")

#: Upper bound on the elements of one (chunk, k, n_places) working array. About
#: ten such float64/intp arrays are alive at once, so the peak is ~320 MB.
_MAX_ELEMENTS: Final[int] = 4_000_000


def _prob2d(prob: np.ndarray) -> np.ndarray:
    p = np.asarray(prob, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] == 0:
        raise ValueError(f"prob must be 2-D (n_queries, n_places>0), got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("prob contains NaN or infinite values")
    if np.any(p < 0):
        raise ValueError("prob contains negative values")
    return p


def _positions(frame_positions: np.ndarray | None, n: int) -> np.ndarray:
    if frame_positions is None:
        return np.arange(n, dtype=np.float64)
    t = np.asarray(frame_positions, dtype=np.float64)
    if t.shape != (n,):
        raise ValueError(f"frame_positions must have shape ({n},), got {t.shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError("frame_positions contains NaN or infinite values")
    if np.any(np.diff(t) < 0):
        raise ValueError("frame_positions must be non-decreasing in stream order")
    return t


def _velocities(velocity: float | np.ndarray, n: int) -> np.ndarray:
    v = np.asarray(velocity, dtype=np.float64)
    if v.ndim == 0:
        v = np.full(n, float(v))
    if v.shape != (n,):
        raise ValueError(f"velocity must be a float or have shape ({n},), got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError("velocity contains NaN or infinite values")
    return v


def _check_args(k: int, rule: str, eps: float) -> int:
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise ValueError(f"window size k must be an integer >= 1, got {k!r}")
    if rule not in RULES:
        raise ValueError(f"unknown aggregation rule {rule!r}; expected one of {RULES}")
    if not (np.isfinite(eps) and eps > 0):
        raise ValueError(f"eps must be a finite value > 0, got {eps}")
    return int(k)


def shift_window(
    prob: np.ndarray,
    queries: np.ndarray,
    k: int,
    velocity: np.ndarray,
    frame_positions: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Shifted window distributions for some queries, shape ``(len(queries), k, n_places)``.

    Offset ``o`` (0 = the query frame itself) holds frame ``m = j - o``:

    .. math:: \\tilde P_{j,o}(l) = (1 - f) P_m(\\lfloor x \\rfloor) + f P_m(\\lfloor x \\rfloor + 1),
              \\quad x = l - v_j (t_j - t_m), \\quad f = x - \\lfloor x \\rfloor

    and ``0`` where ``x`` lies outside ``[0, n_places - 1]`` (the route beyond
    the map). Returns ``(shifted, valid)``; ``valid[c, o]`` is False where
    ``m < 0`` (before the start of the stream); those rows are 0 and must be
    left out of the combination. Inputs must already be validated float64.
    """
    n_places = prob.shape[1]
    offsets = np.arange(k)
    frames = queries[:, None] - offsets[None, :]  # (C, k)
    valid = frames >= 0
    frames_safe = np.where(valid, frames, 0)
    dist = frame_positions[queries][:, None] - frame_positions[frames_safe]  # (C, k)
    x = np.arange(n_places, dtype=np.float64)[None, None, :] - (
        velocity[queries][:, None, None] * dist[:, :, None]
    )  # (C, k, P)
    x0 = np.floor(x)
    frac = x - x0
    inside = (x >= 0) & (x <= n_places - 1) & valid[:, :, None]
    i0 = np.clip(x0, 0, n_places - 1).astype(np.intp)
    i1 = np.clip(x0 + 1, 0, n_places - 1).astype(np.intp)
    rows = frames_safe[:, :, None]
    left = prob[rows, i0]
    right = prob[rows, i1]
    # frac == 0 exactly for an integral shift, so the right neighbour drops out
    shifted = (1.0 - frac) * left + frac * right
    shifted[~inside] = 0.0
    return shifted, valid


def _combine(shifted: np.ndarray, valid: np.ndarray, rule: str, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """Combine the window (product: softmax of summed logs; sum: L1 of the sum).

    Also returns the window score max_l A_j(l) of the un-normalised aggregate
    (the best joint log-likelihood for the product rule, the best summed
    probability for the sum rule), which the velocity search maximises.
    """
    n_places = shifted.shape[2]
    if rule == "product":
        logs = np.log(shifted + eps) * valid[:, :, None]
        a = logs.sum(axis=1)
        peak = a.max(axis=1, keepdims=True)
        e = np.exp(a - peak)
        return e / e.sum(axis=1, keepdims=True), peak[:, 0]
    a = shifted.sum(axis=1)
    total = a.sum(axis=1, keepdims=True)
    out = a / np.where(total > 0, total, 1.0)
    out[total[:, 0] <= 0, :] = 1.0 / n_places
    return out, a.max(axis=1)


def aggregate(
    prob: np.ndarray,
    k: int,
    velocity: float | np.ndarray,
    rule: str = "product",
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

    ``velocity``: places per frame unit, a float or one value per query
    (negative = the route is traversed against the reference order).
    ``frame_positions`` (``t``): non-decreasing frame index / timestamp per
    query as the robot knows it, default ``arange(n_queries)``; a dropped frame
    simply makes ``t_j - t_m`` larger. ``eps`` (product rule only, default
    1e-6) floors every factor so that one frame with probability 0 at a place
    cannot veto it; the product rule is computed in log space and normalised
    with a stable softmax. A sum-rule window that is 0 everywhere returns the
    uniform distribution. ``k == 1`` returns ``prob`` unchanged (an exact
    float64 copy). Never takes ground truth: windows come from stream order
    and ``frame_positions`` only.
    """
    return _aggregate_scored(prob, k, velocity, rule, frame_positions, eps)[0]


def _aggregate_scored(
    prob: np.ndarray,
    k: int,
    velocity: float | np.ndarray,
    rule: str,
    frame_positions: np.ndarray | None,
    eps: float,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`aggregate` plus each window's score max_l A_j(l) (see :func:`_combine`)."""
    p = _prob2d(prob)
    k = _check_args(k, rule, eps)
    n_queries, n_places = p.shape
    t = _positions(frame_positions, n_queries)
    v = _velocities(velocity, n_queries)
    if k == 1:
        return p.copy(), p.max(axis=1)
    out = np.empty_like(p)
    score = np.empty(n_queries)
    chunk = max(1, _MAX_ELEMENTS // (k * n_places))
    for start in range(0, n_queries, chunk):
        queries = np.arange(start, min(start + chunk, n_queries))
        shifted, valid = shift_window(p, queries, k, v, t)
        out[queries], score[queries] = _combine(shifted, valid, rule, eps)
    return out, score


def estimate_velocity(
    prob: np.ndarray,
    k: int,
    candidates: np.ndarray,
    rule: str = "product",
    frame_positions: np.ndarray | None = None,
    eps: float = 1e-6,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-query velocity search over a candidate grid; returns ``(velocity, aggregated)``.

    .. math:: \\hat v_j = \\arg\\max_{v \\in \\mathcal{V}} \\max_l A_j^{(v)}(l)

    where ``A^{(v)}`` is the un-normalised aggregate of :func:`aggregate` at
    velocity v (summed logs for the product rule, summed probabilities for the
    sum rule): for every query the candidate whose window explains the frames
    best wins (ties: the first candidate in the given order). The normalised
    peak is not used: it rewards velocities that pile the window onto one
    place whatever the frames say. Returns the chosen velocity per
    query, shape ``(n_queries,)``, and the aggregated distributions at that
    velocity, shape ``(n_queries, n_places)``. Uses the query frames and their
    window only (no ground truth). With ``k == 1`` every candidate gives the
    same result and the first is returned.
    """
    cands = np.asarray(candidates, dtype=np.float64).ravel()
    if cands.size == 0:
        raise ValueError("candidates must contain at least one velocity")
    p = _prob2d(prob)
    best_v = np.full(p.shape[0], cands[0])
    best, best_peak = _aggregate_scored(p, k, float(cands[0]), rule, frame_positions, eps)
    for c in cands[1:]:
        agg, peak = _aggregate_scored(p, k, float(c), rule, frame_positions, eps)
        better = peak > best_peak
        best_v[better] = c
        best[better] = agg[better]
        best_peak[better] = peak[better]
    return best_v, best
