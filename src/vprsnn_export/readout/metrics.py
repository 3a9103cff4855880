"""Exact precision-recall metrics for single-match place recognition.

Every query has exactly one true place in the reference map and receives one prediction (or a no-match). A
confidence threshold tau accepts the queries with confidence >= tau; a query is a true positive when it is accepted
and correct. Instead of sweeping a fixed grid of thresholds (which can under-estimate R@100P, field notes Sec. 1),
every distinct confidence value is one operating point, computed exactly from the queries sorted by confidence.
Equal confidences are never split: they are accepted or rejected together.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.io.serial import JsonDataclass, json_options

from .assignment import finite_array

METRICS = ("accuracy", "p_at_100r", "r_at_100p", "auc_pr")


def predicted_place_ids(pred_index: np.ndarray, place_ids: np.ndarray) -> np.ma.MaskedArray:
    """Map predicted place indices to place ids; no-matches (index -1) are masked.

    .. math:: \\mathrm{id}_q = \\mathrm{place\\_ids}[\\hat l_q] \\text{ if } \\hat l_q \\ge 0, \\text{ else masked}

    The result can be passed straight to :func:`is_correct`, which never counts a masked (no-match) entry as
    correct. This avoids the classic bug of ``place_ids[-1]`` silently turning a no-match into the last place.
    """
    idx = np.asarray(pred_index)
    ids = np.asarray(place_ids)
    if idx.ndim != 1 or ids.ndim != 1:
        raise InvalidValueError("pred_index and place_ids must be 1-D")
    if not np.issubdtype(idx.dtype, np.integer):
        raise InvalidValueError("pred_index must be an integer array")
    if np.any(idx < -1) or np.any(idx >= ids.shape[0]):
        raise InvalidValueError(f"pred_index must lie in [-1, {ids.shape[0] - 1}]")
    matched = idx >= 0
    values = ids[np.where(matched, idx, 0)] if ids.shape[0] else np.zeros(idx.shape, ids.dtype)
    return np.ma.MaskedArray(values, mask=~matched)


def is_correct(
    pred_place_ids: np.ndarray | np.ma.MaskedArray,
    true_place_ids: np.ndarray,
    tolerance: float = 0,
    *,
    matched: np.ndarray | None = None,
) -> np.ndarray:
    """Whether each query's prediction is correct, boolean array ``(n_queries,)``.

    .. math:: \\mathrm{correct}_q = \\mathrm{matched}_q \\wedge |\\mathrm{pred}_q - \\mathrm{true}_q| \\le \\mathrm{tolerance}

    ``tolerance`` is in place-id units (0 = exact match); a data set's ground truth judges through
    :class:`vprsnn_export.data.truth.GroundTruth` instead. A no-match is never correct. Mark no-matches either by
    passing a masked array (:func:`predicted_place_ids`) or with the boolean ``matched`` mask (False = no-match; the
    value of ``pred_place_ids`` there is ignored); both combine with AND. With neither, every prediction is a match.
    """
    if tolerance < 0 or not np.isfinite(tolerance):
        raise InvalidValueError(f"tolerance must be a finite value >= 0, got {tolerance}")
    ok = ~np.ma.getmaskarray(pred_place_ids)  # all True for a plain array
    pred = np.asarray(np.ma.filled(pred_place_ids, 0))
    true = np.asarray(true_place_ids)
    if pred.ndim != 1 or pred.shape != true.shape:
        raise InvalidValueError(
            f"pred_place_ids {pred.shape} and true_place_ids {true.shape} must be 1-D of equal length"
        )
    if matched is not None:
        m = np.asarray(matched)
        if m.dtype != np.bool_ or m.shape != pred.shape:
            raise InvalidValueError("matched must be a boolean array with one entry per query")
        ok &= m
    return ok & (np.abs(pred.astype(np.float64) - true.astype(np.float64)) <= tolerance)


def operating_points(correct: np.ndarray, confidence: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(TP_k, accepted_k, tau_k, N) for every distinct confidence tau_k, descending."""
    c = np.asarray(correct)
    conf = finite_array("confidence", confidence)
    if c.ndim != 1 or conf.shape != c.shape:
        raise InvalidValueError(f"correct {c.shape} and confidence {conf.shape} must be 1-D of equal length")
    if c.shape[0] == 0:
        raise InvalidValueError("no queries: precision and recall are undefined")
    if c.dtype != np.bool_ and not np.all((c == 0) | (c == 1)):
        raise InvalidValueError("correct must be boolean (or 0/1)")
    c = c.astype(bool, copy=False)
    order = np.argsort(-conf, kind="stable")
    conf_sorted = conf[order]
    tp_cum = np.cumsum(c[order], dtype=np.int64)
    ends = np.flatnonzero(np.append(conf_sorted[1:] != conf_sorted[:-1], True))  # each run of ties' last position
    return tp_cum[ends], ends + 1, conf_sorted[ends], int(c.shape[0])


def pr_curve(correct: np.ndarray, confidence: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact precision-recall operating points, one per distinct confidence value.

    For each distinct confidence tau_k (descending), accept every query with confidence >= tau_k:

    .. math:: P_k = \\frac{TP_k}{\\#\\{q : c_q \\ge \\tau_k\\}}, \\qquad
              R_k = \\frac{TP_k}{N_{queries}}, \\qquad
              TP_k = \\#\\{q : c_q \\ge \\tau_k \\wedge \\mathrm{correct}_q\\}

    Recall divides by the number of queries because every query has a true match in the reference map. Ties are
    never split. No-matches (confidence 0, never correct) are ordinary queries accepted only at the lowest
    thresholds. Returns ``(precision, recall, thresholds)``, float64 of equal length, thresholds strictly
    decreasing, recall non-decreasing; the last point accepts every query.
    """
    tp, accepted, thresholds, n = operating_points(correct, confidence)
    return tp / accepted, tp / n, thresholds


def pr_metrics(correct: np.ndarray, confidence: np.ndarray) -> dict[str, float | int]:
    """Accuracy, P@100R, R@100P and AUC-PR, computed exactly.

    .. math::
        \\mathrm{accuracy} = \\frac{\\#\\mathrm{correct}}{N}, \\qquad
        \\mathrm{P@100R} = P_K \\;(\\text{all queries accepted}), \\qquad
        \\mathrm{R@100P} = \\max\\{R_k : P_k = 1\\} \\;(0 \\text{ if none})

        \\mathrm{AUC\\text{-}PR} = \\sum_k (R_k - R_{k-1})\\, P_k, \\quad R_0 = 0

    over the operating points of :func:`pr_curve` (the exact area under the step curve, i.e. average precision).
    With single-match VPR every query has one true place and one prediction, so accepting all queries gives
    precision = #correct / N: **P@100R always equals accuracy** (field notes Sec. 1); it is reported for comparison
    with the literature. Returns floats in [0, 1] and ``n_queries`` (an int); empty input raises ``ValueError``.
    """
    tp, accepted, _, n = operating_points(correct, confidence)
    precision = tp / accepted
    recall = tp / n
    perfect = tp == accepted  # precision 1, tested exactly in integers
    return {
        "accuracy": int(tp[-1]) / n,  # the last point accepts every query
        "p_at_100r": float(precision[-1]),
        "r_at_100p": float(recall[perfect].max()) if np.any(perfect) else 0.0,
        "auc_pr": float(np.sum(np.diff(recall, prepend=0.0) * precision)),
        "n_queries": n,
    }


@dataclass(frozen=True)
class MetricValues(JsonDataclass):
    """Accuracy, P@100R, R@100P and AUC-PR of one readout (fractions in [0, 1], or their differences)."""

    accuracy: float
    p_at_100r: float
    r_at_100p: float
    auc_pr: float

    def get(self, metric: str) -> float:
        """The value of one metric by name (one of ``METRICS``)."""
        if metric not in METRICS:
            raise KeyError(metric)
        return float(getattr(self, metric))


@dataclass(frozen=True)
class MetricRow(JsonDataclass):
    """One readout (strategy at k) of one network; quantised rows carry the float values and the deltas."""

    strategy: str
    k: int
    values: MetricValues = field(metadata=json_options(flatten=True))
    n_queries: int
    float_values: MetricValues | None = field(default=None, metadata=json_options(key="float", omit="none"))
    delta: MetricValues | None = field(default=None, metadata=json_options(omit="none"))  # quantised - float

    @property
    def accuracy(self) -> float:
        return self.values.accuracy

    @property
    def p_at_100r(self) -> float:
        return self.values.p_at_100r

    @property
    def r_at_100p(self) -> float:
        return self.values.r_at_100p

    @property
    def auc_pr(self) -> float:
        return self.values.auc_pr

    def with_float(self, base: MetricRow) -> MetricRow:
        """This row with the float row's values and the differences (this - float), metric by metric."""
        delta = MetricValues(*(self.values.get(m) - base.values.get(m) for m in METRICS))
        return MetricRow(self.strategy, self.k, self.values, self.n_queries, base.values, delta)


def metric_row(strategy: str, k: int, metrics: Mapping) -> MetricRow:
    """The typed row of one readout from :func:`pr_metrics`' values."""
    return MetricRow.from_dict({"strategy": strategy, "k": k, **metrics})


def find_row(rows: Sequence[MetricRow], strategy: str, k: int) -> MetricRow | None:
    """The row of ``strategy`` at ``k``, or None."""
    return next((r for r in rows if r.strategy == strategy and r.k == k), None)
