"""Neuron-to-place assignment and per-query place scores (paper Sec. III-E).

Notation (paper Sec. III-E):

* ``sr`` = S^R, shape ``(n_neurons, n_places)``: calibration spike counts, the
  training set re-presented with plasticity off; ``S^R[i, l]`` is the number of
  spikes neuron ``i`` emitted for place ``l``.
* ``sq`` = S^Q, shape ``(n_queries, n_neurons)``: spike counts of every neuron
  for every query image.

Three strategies turn them into one row of place scores per query:

* ``"standard"`` -- each neuron votes for its best calibration place.
* ``"weighted"`` -- eq. 9-11: involvement regularisation, response-strength
  normalisation and the missing-spikes penalty.
* ``"wprob"`` -- eq. 12-13: the weighted scores min-max normalised and then
  L1-normalised into a distribution P(l | Q).

:mod:`readout.strategies` registers them (scores, confidence, title) and
:func:`~vprsnn_export.readout.strategies.decide` turns scores into a predicted place
index (``-1`` = no match) and a confidence. Everything is float64 numpy, vectorised over queries,
neurons and places (matrix products and fancy indexing only).
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from typing import Any, Final

import numpy as np

from vprsnn_export.arguments import real_array, real_number
from vprsnn_export.errors import InvalidValueError

#: Predicted place index that means "no match" (the query is rejected).
NO_MATCH: Final[int] = -1

#: The last query-independent result of each function, by the S^R array it was computed from (that very object,
#: alive: a weak reference) and its other arguments: a readout reading its queries in blocks computes it once.
_LAST: dict[str, tuple[weakref.ref, tuple, Any]] = {}


def once_per_calibration(name: str, sr: np.ndarray, key: tuple, compute: Callable[[], Any]) -> Any:
    """``compute()``, or what it gave for this very ``sr`` object and ``key`` last time (S^R is never changed in
    place by the project: a new calibration is a new array)."""
    last = _LAST.get(name)
    if last is not None and last[0]() is sr and last[1] == key:
        return last[2]
    value = compute()
    _LAST[name] = (weakref.ref(sr), key, value)
    return value


def _counts(name: str, a: np.ndarray) -> np.ndarray:
    """Validate a 2-D, finite, non-negative count array and return it as float64."""
    arr = real_array(name, a)
    if arr.ndim != 2:
        raise InvalidValueError(f"{name} must be 2-D, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidValueError(f"{name} contains NaN or infinite values")
    if np.any(arr < 0):
        raise InvalidValueError(f"{name} contains negative spike counts")
    return arr


def _pair(sr: np.ndarray, sq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    sr_ = _counts("sr", sr)
    sq_ = _counts("sq", sq)
    if sq_.shape[1] != sr_.shape[0]:
        raise InvalidValueError(f"sq has {sq_.shape[1]} neurons per query but sr has {sr_.shape[0]} neurons")
    return sr_, sq_


def _scores2d(scores: np.ndarray) -> np.ndarray:
    arr = real_array("scores", scores)
    if arr.ndim != 2 or arr.shape[1] == 0:
        raise InvalidValueError(f"scores must be 2-D (n_queries, n_places>0), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidValueError("scores contain NaN or infinite values")
    return arr


def standard_assignment(sr: np.ndarray) -> np.ndarray:
    """One-hot neuron-to-place assignment matrix A, shape ``(n_neurons, n_places)``.

    .. math:: l^*_i = \\arg\\max_l S^R_{il}, \\qquad A_{il} = [\\,l = l^*_i \\wedge \\textstyle\\sum_m S^R_{im} > 0\\,]

    Ties go to the lowest place index (``np.argmax``). A neuron that never
    spiked during calibration (an all-zero row) is assigned to no place: its
    row of A is all zero.
    """
    sr_ = _counts("sr", sr)
    n_neurons, n_places = sr_.shape
    one_hot = np.zeros((n_neurons, n_places), dtype=np.float64)
    if n_places == 0 or n_neurons == 0:
        return one_hot
    best = np.argmax(sr_, axis=1)
    active = sr_.sum(axis=1) > 0
    rows = np.flatnonzero(active)
    one_hot[rows, best[rows]] = 1.0
    return one_hot


def standard_scores(sr: np.ndarray, sq: np.ndarray) -> np.ndarray:
    """Standard (argmax) assignment scores, shape ``(n_queries, n_places)``.

    .. math:: \\mathrm{Score}_{ql} = \\sum_{i:\\, l^*_i = l} S^Q_{qi} = (S^Q A)_{ql}

    with ``A = standard_assignment(sr)`` (ties to the lowest place index;
    neurons silent during calibration belong to no place and never vote).
    The product with the one-hot A is a sum of the columns of S^Q grouped by
    place (``np.add.reduceat``): O(queries x neurons), not a dense matrix product;
    the counts are integers, so the sums are exact either way.
    """
    sr_, sq_ = _pair(sr, sq)
    scores = np.zeros((sq_.shape[0], sr_.shape[1]), dtype=np.float64)
    if sr_.size == 0:
        return scores
    voters, places, starts = once_per_calibration("voters", sr_, (), lambda: standard_voters(sr_))
    if voters.size == 0:
        return scores
    scores[:, places] = np.add.reduceat(sq_[:, voters], starts, axis=1)
    return scores


def standard_voters(sr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The neurons that vote (fired in calibration), ordered by their best place, with each place they vote for
    and where its voters start: :math:`l^*_i = \\arg\\max_l S^R_{il}` (ties to the lowest index)."""
    voters = np.flatnonzero(sr.sum(axis=1) > 0)
    best = np.argmax(sr[voters], axis=1)
    order = np.argsort(best, kind="stable")
    voters, best = voters[order], best[order]
    places, starts = np.unique(best, return_index=True)
    return voters, places, starts


def weighted_matrix(sr: np.ndarray, gamma: float) -> np.ndarray:
    """The weighted-assignment matrix S'' of eq. 9-10, shape ``(n_neurons, n_places)``.

    .. math::
        \\omega_i = \\#\\{l : S^R_{il} > 0\\}, \\qquad
        S'_{il} = \\begin{cases} S^R_{il} / \\omega_i & \\omega_i > \\gamma N_{places} \\\\
                                 S^R_{il} & \\text{otherwise} \\end{cases}

        S''_{il} = S'_{il} \\, \\frac{S^R_{il}}{\\sum_m S^R_{im}}

    A neuron silent during calibration has ``S''_{i\\cdot} = 0``.
    ``gamma`` is the involvement threshold, in [0, 1] (the paper: (0, 1)).
    """
    sr_ = _counts("sr", sr)
    gamma = real_number("gamma", gamma)
    if not (0.0 <= gamma <= 1.0):
        raise InvalidValueError(f"gamma must lie in [0, 1], got {gamma}")
    n_places = sr_.shape[1]
    omega = np.count_nonzero(sr_ > 0, axis=1).astype(np.float64)
    penalised = omega > gamma * n_places  # implies omega >= 1
    divisor = np.where(penalised, omega, 1.0)
    s_prime = sr_ / divisor[:, None]
    rowsum = sr_.sum(axis=1)
    safe = np.where(rowsum > 0, rowsum, 1.0)
    return s_prime * (sr_ / safe[:, None])  # a silent row is 0 * 0 = 0


def missing_spikes_penalty(sr: np.ndarray, sq: np.ndarray) -> np.ndarray:
    """Missing-spikes penalty factor of eq. 11, shape ``(n_queries, n_places)``.

    .. math:: \\mathrm{pen}_{ql} = \\frac{\\sum_{m \\in \\mathrm{Active}_q} S^R_{ml}}{\\sum_m S^R_{ml}}
              = \\frac{([S^Q > 0]\\, S^R)_{ql}}{\\sum_m S^R_{ml}}

    ``Active_q`` = neurons with at least one spike in query q. The factor is 0
    for a place whose calibration column sum is 0.
    """
    sr_, sq_ = _pair(sr, sq)
    colsum = sr_.sum(axis=0)
    safe = np.where(colsum > 0, colsum, 1.0)
    active = (sq_ > 0).astype(np.float64)
    pen = (active @ sr_) / safe[None, :]
    pen[:, colsum <= 0] = 0.0
    return pen


def weighted_scores(sr: np.ndarray, sq: np.ndarray, gamma: float) -> np.ndarray:
    """Weighted-assignment scores (eq. 9-11), shape ``(n_queries, n_places)``.

    .. math:: \\mathrm{Score}_{ql} = \\Big(\\sum_i S^Q_{qi} S''_{il}\\Big)
              \\frac{\\sum_{m \\in \\mathrm{Active}_q} S^R_{ml}}{\\sum_m S^R_{ml}}

    with S'' from :func:`weighted_matrix` (eq. 9-10) and the penalty from
    :func:`missing_spikes_penalty` (eq. 11). Scores are non-negative; a query
    with no spike at all scores 0 everywhere.
    """
    sr_, sq_ = _pair(sr, sq)
    weighting = once_per_calibration("weighted", sr_, (float(gamma),), lambda: weighted_matrix(sr_, gamma))
    return (sq_ @ weighting) * missing_spikes_penalty(sr_, sq_)


def wprob_distribution(scores: np.ndarray) -> np.ndarray:
    """Probability-based assignment P(l | Q) (eq. 12-13), shape ``(n_queries, n_places)``.

    .. math::
        \\widehat{\\mathrm{Score}}_l = \\frac{\\mathrm{Score}_l - \\min_m \\mathrm{Score}_m}
                                            {\\max_m \\mathrm{Score}_m - \\min_m \\mathrm{Score}_m},
        \\qquad P(l \\mid Q) = \\frac{\\widehat{\\mathrm{Score}}_l}{\\sum_m \\widehat{\\mathrm{Score}}_m}

    Choice: when ``max == min`` for a query (all scores equal, e.g. a query
    that produced no spike) eq. 12 is 0/0; that query gets the uniform
    distribution ``1/n_places``, which ``strategies.decide`` reports as a no-match.
    Otherwise the best place has normalised score 1, so the L1 sum is >= 1
    and never 0.
    """
    s = _scores2d(scores)
    lo = s.min(axis=1, keepdims=True)
    hi = s.max(axis=1, keepdims=True)
    span = hi - lo
    flat = span[:, 0] <= 0
    norm = (s - lo) / np.where(span > 0, span, 1.0)
    total = norm.sum(axis=1, keepdims=True)
    out = norm / np.where(total > 0, total, 1.0)
    out[flat, :] = 1.0 / s.shape[1]
    return out


def share_confidence(scores: np.ndarray) -> np.ndarray:
    """Confidence of the Standard and Weighted strategies, shape ``(n_queries,)``.

    .. math:: c_q = \\frac{\\max_l \\mathrm{Score}_{ql}}{\\sum_l \\mathrm{Score}_{ql}}

    (0 when the sum is 0). Scores must be non-negative, so c lies in [0, 1].
    For W+Prob the confidence is ``max_l P(l | Q)`` instead (:func:`distribution_decision`).
    """
    s = _scores2d(scores)
    if np.any(s < 0):
        raise InvalidValueError("share_confidence needs non-negative scores")
    total = s.sum(axis=1)
    top = s.max(axis=1)
    return np.where(total > 0, top / np.where(total > 0, total, 1.0), 0.0)


def share_decision(scores: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """No-match mask and confidence of score rows (Standard, Weighted).

    .. math:: \\mathrm{no\\ match}_q = [\\forall l: \\mathrm{Score}_{ql} = 0], \\qquad
              c_q = \\max_l \\mathrm{Score}_{ql} / \\sum_l \\mathrm{Score}_{ql}
    """
    s = _scores2d(scores)
    return np.all(s == 0, axis=1), share_confidence(s)


def distribution_decision(distribution: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """No-match mask and confidence of distribution rows (W+Prob, aggregated, SAD).

    .. math:: \\mathrm{no\\ match}_q = [\\max_l P(l \\mid Q_q) = \\min_l P(l \\mid Q_q)], \\qquad
              c_q = \\max_l P(l \\mid Q_q)

    A flat row (every entry equal, e.g. the uniform distribution of
    :func:`wprob_distribution`) is a no-match.
    """
    s = _scores2d(distribution)
    top = s.max(axis=1)
    return top == s.min(axis=1), top.copy()
