"""Neuron-to-place assignment and per-query place scores (paper Sec. III-E).

* ``sr`` = S^R, shape ``(n_neurons, n_places)``: calibration spike counts, the training set re-presented with
  plasticity off; ``S^R[i, l]`` is the number of spikes neuron ``i`` emitted for place ``l``.
* ``sq`` = S^Q, shape ``(n_queries, n_neurons)``: spike counts of every neuron for every query image.

Three strategies turn them into one row of place scores per query:

* ``"standard"`` -- each neuron votes for its best calibration place.
* ``"weighted"`` -- eq. 9-11: involvement regularisation, response-strength normalisation and the missing-spikes
  penalty.
* ``"wprob"`` -- eq. 12-13: the weighted scores min-max normalised and then L1-normalised into a distribution P(l | Q).

:mod:`readout.strategies` registers them. S^R, S'' and S^Q are float64 CSR arrays and every product runs over
their stored entries; the scores come out dense, (queries, places).
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from typing import Any, Final

import numpy as np
from scipy import sparse

from vprsnn_export.arguments import real_array, real_number
from vprsnn_export.errors import InvalidValueError

from .rules import l1_finish

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


def finite_array(name: str, value: object) -> np.ndarray:
    """``value`` as a float64 array of finite real numbers; InvalidValueError naming ``name`` otherwise."""
    arr = real_array(name, value)
    if not np.all(np.isfinite(arr)):
        raise InvalidValueError(f"{name} contains NaN or infinite values")
    return arr


def finite_matrix(name: str, value: object) -> np.ndarray:
    """``value`` as a finite float64 (rows, columns > 0) array; InvalidValueError naming ``name`` otherwise."""
    arr = real_array(name, value)
    if arr.ndim != 2 or arr.shape[1] == 0:
        raise InvalidValueError(f"{name} must be 2-D (n_queries, n_places>0), got shape {arr.shape}")
    return finite_array(name, arr)


def _checked_counts(name: str, shape: tuple, values: np.ndarray) -> np.ndarray:
    """``values`` (or a sparse array's stored entries) when 2-D, finite and >= 0; InvalidValueError naming ``name``."""
    if len(shape) != 2:
        raise InvalidValueError(f"{name} must be 2-D, got shape {shape}")
    if not np.all(np.isfinite(values)):
        raise InvalidValueError(f"{name} contains NaN or infinite values")
    if np.any(values < 0):
        raise InvalidValueError(f"{name} contains negative spike counts")
    return values


def sparse_counts(name: str, a: np.ndarray | sparse.sparray) -> sparse.csr_array:
    """A count array, dense or scipy.sparse, checked (2-D, finite, non-negative) as float64 CSR with sorted column
    indices and no stored zeros (row by row in column order: the same sums whatever the block of rows)."""
    if not sparse.issparse(a) or a.ndim != 2:
        arr = real_array(name, a.toarray() if sparse.issparse(a) else a)  # type: ignore[union-attr]
        return sparse.csr_array(_checked_counts(name, arr.shape, arr))
    if isinstance(a, sparse.csr_array) and a.dtype == np.float64 and a.has_canonical_format:
        _checked_counts(name, a.shape, a.data)
        if np.all(a.data != 0):  # already in the readout's form (S~ read block after block): no copy
            return a
    out = sparse.csr_array(a, dtype=np.float64, copy=True)
    _checked_counts(name, out.shape, np.asarray(out.data))
    out.sum_duplicates()
    out.eliminate_zeros()
    return out


def entry_rows(a: sparse.csr_array) -> np.ndarray:
    """The row of every stored entry of a CSR array, in storage order: :math:`i` repeated once per entry of row i."""
    return np.repeat(np.arange(a.shape[0]), np.diff(a.indptr))


def like_input(result: sparse.csr_array, original: object) -> np.ndarray | sparse.csr_array:
    """``result`` as the caller gave its input: CSR for a sparse array, else dense."""
    return result if sparse.issparse(original) else result.toarray()


def count_pair(sr: np.ndarray, sq: np.ndarray) -> tuple[sparse.csr_array, sparse.csr_array]:
    """S^R and S^Q as :func:`sparse_counts`, S^Q with one column per neuron of S^R."""
    sr_ = sparse_counts("sr", sr)
    sq_ = sparse_counts("sq", sq)
    if sq_.shape[1] != sr_.shape[0]:
        raise InvalidValueError(f"sq has {sq_.shape[1]} neurons per query but sr has {sr_.shape[0]} neurons")
    return sr_, sq_


def standard_assignment(sr: np.ndarray) -> np.ndarray:
    """One-hot neuron-to-place assignment matrix A, shape ``(n_neurons, n_places)``.

    .. math:: l^*_i = \\arg\\max_l S^R_{il}, \\qquad A_{il} = [\\,l = l^*_i \\wedge \\textstyle\\sum_m S^R_{im} > 0\\,]

    Ties go to the lowest place; a neuron silent in calibration has no place. :func:`standard_voters`: sparse.
    """
    return standard_voters(sparse_counts("sr", sr)).toarray()


def standard_scores(sr: np.ndarray, sq: np.ndarray) -> np.ndarray:
    """Standard (argmax) assignment scores, shape ``(n_queries, n_places)``.

    .. math:: \\mathrm{Score}_{ql} = \\sum_{i:\\, l^*_i = l} S^Q_{qi} = (S^Q A)_{ql}

    with ``A = standard_assignment(sr)``, a sparse product (integer counts: exact sums).
    """
    sr_, sq_ = count_pair(sr, sq)
    return (sq_ @ once_per_calibration("voters", sr, (), lambda: standard_voters(sr_))).toarray()


def standard_voters(sr: sparse.csr_array) -> sparse.csr_array:
    """A of :func:`standard_assignment` as CSR (float64, one entry per neuron that fired in calibration):
    :math:`l^*_i = \\arg\\max_l S^R_{il}` (ties to the lowest index: a CSR row's columns are sorted)."""
    voters = np.flatnonzero(np.diff(sr.indptr) > 0)
    best = np.asarray(sr.argmax(axis=1)).ravel()[voters]
    return sparse.csr_array((np.ones(len(voters)), (voters, best)), shape=sr.shape)


def weighted_matrix(sr: np.ndarray, gamma: float) -> np.ndarray | sparse.csr_array:
    """The weighted-assignment matrix S'' of eq. 9-10, shape ``(n_neurons, n_places)``, dense or CSR as S^R.

    .. math::
        \\omega_i = \\#\\{l : S^R_{il} > 0\\}, \\qquad
        S'_{il} = \\begin{cases} S^R_{il} / \\omega_i & \\omega_i > \\gamma N_{places} \\\\
                                 S^R_{il} & \\text{otherwise} \\end{cases}

        S''_{il} = S'_{il} \\, \\frac{S^R_{il}}{\\sum_m S^R_{im}}

    ``gamma``: the involvement threshold in [0, 1]; a neuron silent in calibration has ``S''_{i\\cdot} = 0``.
    """
    sr_ = sparse_counts("sr", sr)
    gamma = real_number("gamma", gamma)
    if not (0.0 <= gamma <= 1.0):
        raise InvalidValueError(f"gamma must lie in [0, 1], got {gamma}")
    omega = np.diff(sr_.indptr).astype(np.float64)  # stored entries are the positive ones
    divisor = np.where(omega > gamma * sr_.shape[1], omega, 1.0)  # penalised: omega >= 1
    rowsum = np.asarray(sr_.sum(axis=1)).ravel()
    rows = entry_rows(sr_)
    data = (sr_.data / divisor[rows]) * (sr_.data / rowsum[rows])
    return like_input(sparse.csr_array((data, sr_.indices, sr_.indptr), shape=sr_.shape), sr)


def missing_spikes_penalty(sr: np.ndarray, sq: np.ndarray) -> np.ndarray:
    """Missing-spikes penalty factor of eq. 11, shape ``(n_queries, n_places)``.

    .. math:: \\mathrm{pen}_{ql} = \\frac{\\sum_{m \\in \\mathrm{Active}_q} S^R_{ml}}{\\sum_m S^R_{ml}}
              = \\frac{([S^Q > 0]\\, S^R)_{ql}}{\\sum_m S^R_{ml}}

    ``Active_q``: the neurons that spiked in query q; 0 for a place whose calibration column sums to 0.
    """
    return _penalty(*count_pair(sr, sq))


def _penalty(sr: sparse.csr_array, sq: sparse.csr_array) -> np.ndarray:
    colsum = np.asarray(sr.sum(axis=0)).ravel()
    active = sparse.csr_array((np.ones_like(sq.data), sq.indices, sq.indptr), shape=sq.shape)
    return (active @ sr).toarray() / np.where(colsum > 0, colsum, 1.0)[None, :]  # 0 / 1 where the column is 0


def weighted_scores(sr: np.ndarray, sq: np.ndarray, gamma: float) -> np.ndarray:
    """Weighted-assignment scores (eq. 9-11), shape ``(n_queries, n_places)``.

    .. math:: \\mathrm{Score}_{ql} = \\Big(\\sum_i S^Q_{qi} S''_{il}\\Big)
              \\frac{\\sum_{m \\in \\mathrm{Active}_q} S^R_{ml}}{\\sum_m S^R_{ml}}

    with S'' from :func:`weighted_matrix` and the penalty of :func:`missing_spikes_penalty`; a query with no
    spike scores 0 everywhere.
    """
    sr_, sq_ = count_pair(sr, sq)
    weighting = once_per_calibration("weighted", sr, (float(gamma),), lambda: weighted_matrix(sr_, gamma))
    return (sq_ @ weighting).toarray() * _penalty(sr_, sq_)


def wprob_distribution(scores: np.ndarray) -> np.ndarray:
    """Probability-based assignment P(l | Q) (eq. 12-13), shape ``(n_queries, n_places)``.

    .. math::
        \\widehat{\\mathrm{Score}}_l = \\frac{\\mathrm{Score}_l - \\min_m \\mathrm{Score}_m}
                                            {\\max_m \\mathrm{Score}_m - \\min_m \\mathrm{Score}_m},
        \\qquad P(l \\mid Q) = \\frac{\\widehat{\\mathrm{Score}}_l}{\\sum_m \\widehat{\\mathrm{Score}}_m}

    Where ``max == min`` (eq. 12 is 0/0, e.g. a query with no spike) the row is uniform, ``1/n_places``: a no-match.
    """
    s = finite_matrix("scores", scores)
    lo = s.min(axis=1, keepdims=True)
    span = s.max(axis=1, keepdims=True) - lo
    return l1_finish((s - lo) / np.where(span > 0, span, 1.0))[0]  # a flat row is 0 everywhere: uniform


def share_confidence(scores: np.ndarray) -> np.ndarray:
    """Confidence of the Standard and Weighted strategies, shape ``(n_queries,)``.

    .. math:: c_q = \\frac{\\max_l \\mathrm{Score}_{ql}}{\\sum_l \\mathrm{Score}_{ql}}

    (0 when the sum is 0); scores must be non-negative.
    """
    s = finite_matrix("scores", scores)
    if np.any(s < 0):
        raise InvalidValueError("share_confidence needs non-negative scores")
    total = s.sum(axis=1)
    return np.where(total > 0, s.max(axis=1) / np.where(total > 0, total, 1.0), 0.0)


def share_decision(scores: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """No-match mask and confidence of score rows (Standard, Weighted), checked by :func:`~.strategies.decide`.

    .. math:: \\mathrm{no\\ match}_q = [\\forall l: \\mathrm{Score}_{ql} = 0], \\qquad
              c_q = \\max_l \\mathrm{Score}_{ql} / \\sum_l \\mathrm{Score}_{ql}
    """
    return np.all(scores == 0, axis=1), share_confidence(scores)


def distribution_decision(distribution: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """No-match mask and confidence of distribution rows (W+Prob, aggregated, SAD).

    .. math:: \\mathrm{no\\ match}_q = [\\max_l P(l \\mid Q_q) = \\min_l P(l \\mid Q_q)], \\qquad
              c_q = \\max_l P(l \\mid Q_q)

    (a flat row is a no-match; the rows come checked from :func:`~.strategies.decide`).
    """
    top = distribution.max(axis=1)
    return top == distribution.min(axis=1), top
