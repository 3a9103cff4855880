"""The checks of `verify`, each a small pure function: tolerances, spike, decision, module and metric level, weights."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import torch

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.readout.compare import sequence_agreement, sequence_distance, strategy_agreement
from vprsnn_export.readout.metrics import MetricRow, find_row
from vprsnn_export.readout.scored import Scored
from vprsnn_export.readout.strategies import SEQUENCE_STRATEGY, STRATEGIES
from vprsnn_export.targets.intsim import step_agreement

from ..measurements import (
    DecisionLevel,
    LevelHistogram,
    ModuleRow,
    PrCurve,
    SpikeLevel,
    ToleranceCheck,
    WeightHistogram,
)

#: Each tolerance's default (a *drop* of at most this much from float: fractions, 0.01 = 1 point; None: off) and
#: what it means (the report's words).
TOLERANCES: dict[str, tuple[float | None, str]] = {
    "accuracy": (0.02, "accuracy drop of every strategy at k=1"),  # Standard, Weighted and W+Prob
    "r_at_100p": (0.01, "R@100P drop of W+Prob at every k (k > 1 only on consecutive queries)"),
    "auc_pr": (None, "AUC-PR drop of W+Prob at the largest k (k = 1 on non-consecutive queries)"),
    "p_at_100r": (None, "P@100R drop of every strategy at k=1"),  # equals accuracy
    "winner_agreement": (None, "fraction of time steps with the float winner, at least"),
    "top1_agreement": (None, "W+Prob k=1 top-1 agreement with float, at least"),
    "saturations": (None, "voltage saturation events on the queries, at most"),
    "query_slack": (1, "metric drops of at most this many queries' worth (n / Q) pass whatever the limit"),
}
DEFAULT_TOLERANCES: dict[str, float | None] = {key: default for key, (default, _) in TOLERANCES.items()}
TOLERANCE_MEANING = {key: meaning for key, (_, meaning) in TOLERANCES.items()}
OFF = ("off", "none", "")


#: Tolerances counted in whole events or queries (the rest are fractions in [0, 1]).
COUNTED = ("saturations", "query_slack")


def parse_tolerances(text: str | None) -> dict[str, float | None]:
    """``"r_at_100p=0.01,accuracy=0.02,auc_pr=off"`` over the defaults; InvalidValueError on anything else: an
    unknown or repeated key, a fraction outside [0, 1], a count (:data:`COUNTED`) that is not a whole number."""
    given: dict[str, float | None] = {}
    for item in (text or "").split(","):
        if not item.strip():
            continue
        key, sep, raw = item.partition("=")
        key, raw = key.strip(), raw.strip().lower()
        if not sep or key not in DEFAULT_TOLERANCES:
            raise InvalidValueError(
                f"--tolerance expects KEY=VALUE with KEY one of {', '.join(DEFAULT_TOLERANCES)} "
                f"(VALUE a number or off), got {item[:80]!r}"
            )
        if key in given:
            raise InvalidValueError(f"--tolerance {key}: given twice; give each key once")
        if raw in OFF:
            given[key] = None
            continue
        try:
            value, counted = float(raw), key in COUNTED
            fits = bool(np.isfinite(value) and value >= 0 and value == int(value)) if counted else 0 <= value <= 1
            expected = "a whole number >= 0" if counted else "a fraction in [0, 1] (0.02 = 2 points)"
        except ValueError:
            fits, expected = False, "a number or off"
        if not fits:
            raise InvalidValueError(f"--tolerance {key}: expected {expected}, got {raw[:40]!r}")
        given[key] = value
    return {**DEFAULT_TOLERANCES, **given}


def count_correlations(float_counts: np.ndarray, int_counts: np.ndarray) -> np.ndarray:
    """Pearson correlation of the float and integer spike-count vectors (over neurons), one per query.

    Where a vector is constant the correlation is undefined: two identical vectors (e.g. both
    silent) count as 1, otherwise 0.
    """
    a, b = (np.asarray(counts, dtype=np.float64) for counts in (float_counts, int_counts))
    da, db = a - a.mean(axis=1, keepdims=True), b - b.mean(axis=1, keepdims=True)
    na, nb = np.sqrt((da * da).sum(axis=1)), np.sqrt((db * db).sum(axis=1))
    defined = (na > 0) & (nb > 0)
    corr = np.where(defined, (da * db).sum(axis=1) / np.where(defined, na * nb, 1.0), 0.0)
    identical = np.all(a == b, axis=1)
    return np.where(~defined & identical, 1.0, corr)


def spike_level(
    float_raster: torch.Tensor,
    int_raster: torch.Tensor,
    float_counts: np.ndarray,
    int_counts: np.ndarray,
    saturations: int,
    calibration_saturations: int | None = None,
) -> SpikeLevel:
    """Winner agreement per step, spike-count correlation per query, total spikes, saturations."""
    agreement = step_agreement(torch.as_tensor(float_raster), torch.as_tensor(int_raster))
    corr = count_correlations(float_counts, int_counts)
    float_total, int_total = (np.asarray(counts).sum(axis=1) for counts in (float_counts, int_counts))
    return SpikeLevel(
        winner_agreement=agreement["all_steps"],
        winner_agreement_active=agreement["active_steps"],
        n_steps=int(agreement["n_steps"]),
        n_active_steps=int(agreement["n_active_steps"]),
        count_correlation_mean=float(corr.mean()),
        count_correlation_min=float(corr.min()),
        count_correlation=tuple(round(float(c), 6) for c in corr),
        total_spikes_float=int(float_total.sum()),
        total_spikes=int(int_total.sum()),
        spike_ratio=float(int_total.sum() / float_total.sum()) if float_total.sum() else None,
        spikes_per_query_float=tuple(int(v) for v in float_total),
        spikes_per_query=tuple(int(v) for v in int_total),
        saturations=int(saturations),
        calibration_saturations=calibration_saturations,
    )


def decision_level(float_scored: Scored, scored: Scored, ks: Sequence[int]) -> DecisionLevel:
    """Top-1 agreement per strategy at k=1, W+Prob total variation, aggregated agreement per k of ``ks``."""
    tv = sequence_distance(float_scored, scored)
    return DecisionLevel(
        top1_agreement=strategy_agreement(float_scored, scored),
        wprob_tv_mean=float(tv.mean()),
        wprob_tv_max=float(tv.max()),
        wprob_tv=tuple(round(float(v), 6) for v in tv),
        aggregated_agreement={int(k): v for k, v in sequence_agreement(float_scored, scored, ks).items()},
    )


def module_rows(
    regions: np.ndarray,
    group: int,
    float_scored: Scored,
    scored: Scored,
    float_raster: torch.Tensor,
    int_raster: torch.Tensor,
) -> tuple[ModuleRow, ...]:
    """Per module of an ensemble: whole-route accuracy on its region's queries (float and quantised, k=1 and the
    largest k), its winner agreement and its spikes (:class:`~runtime.results.ModuleRow`), vectorised over modules."""
    top = max(float_scored.ks)
    (float_1, float_k), (int_1, int_k) = (
        [side.regions(regions, k) for k in (1, top)] for side in (float_scored, scored)
    )
    n, timesteps, _ = float_raster.shape
    a, b = (torch.as_tensor(raster).reshape(n, timesteps, len(regions), group) for raster in (float_raster, int_raster))
    agreement = (a == b).all(dim=3).double().mean(dim=(0, 1)).numpy()
    spikes_float, spikes = (side.sum(dim=(0, 1, 3)).numpy() for side in (a, b))
    return tuple(
        ModuleRow(
            module=region.module,
            first_place=region.first_place,
            last_place=region.last_place,
            n_queries=region.n_queries,
            k=int(top),
            float_accuracy=region.accuracy,
            accuracy=int_1[m].accuracy,
            float_accuracy_k=float_k[m].accuracy,
            accuracy_k=int_k[m].accuracy,
            winner_agreement=float(agreement[m]),
            spikes_float=int(spikes_float[m]),
            spikes=int(spikes[m]),
        )
        for m, region in enumerate(float_1)
    )


def metric_deltas(float_rows: Sequence[MetricRow], rows: Sequence[MetricRow]) -> tuple[MetricRow, ...]:
    """Each quantised row with its float value and the difference (quantised - float) of every metric."""
    reference = {(r.strategy, r.k): r for r in float_rows}
    return tuple(row.with_float(reference[(row.strategy, row.k)]) for row in rows)


def curves(scored: Scored, ks: Sequence[int]) -> dict[str, PrCurve]:
    """PR curves of W+Prob at k=1 and at the largest k of ``ks``, for the report's plots."""
    name = SEQUENCE_STRATEGY
    drawn = {k: scored.column(name, k).curve() for k in sorted({1, max(ks)})}  # (precision, recall)
    return {
        f"{name} k={k}": PrCurve(*(tuple(round(float(v), 6) for v in side) for side in pr)) for k, pr in drawn.items()
    }


def judged_limits(
    tolerances: Mapping[str, float | None], ks: Sequence[int], n_queries: int, *, sequences: bool = True
) -> dict[tuple[str, str, int], float]:
    """(metric, strategy, k) -> the drop limit applied, for every metric tolerance that is on, in this order:
    accuracy and P@100R of every strategy at k=1, R@100P of W+Prob at every judged k of ``ks`` (k = 1 and, on
    consecutive queries (``sequences``), every k > 1), AUC-PR of W+Prob at the largest. A metric moves in steps of
    1/Q, so the limit applied is max(limit, query_slack / Q) (with 30 queries a "1 point" limit would mean "no query
    may change").
    """
    judged = sorted(k for k in set(ks) if k == 1 or sequences)
    slack = float(tolerances.get("query_slack") or 0) / max(n_queries, 1)
    readouts = {
        "accuracy": [(s, 1) for s in STRATEGIES],
        "p_at_100r": [(s, 1) for s in STRATEGIES],
        "r_at_100p": [(SEQUENCE_STRATEGY, k) for k in judged],
        "auc_pr": [(SEQUENCE_STRATEGY, max(judged, default=1))],  # k = 1 is always read out
    }
    return {
        (metric, strategy, k): max(float(limit), slack)
        for metric, pairs in readouts.items()
        if (limit := tolerances.get(metric)) is not None
        for strategy, k in pairs
    }


def tolerance_checks(
    rows: Sequence[MetricRow],
    spike: SpikeLevel,
    decision: DecisionLevel,
    tolerances: Mapping[str, float | None],
    ks: Sequence[int],
    *,
    sequences: bool = True,
) -> list[ToleranceCheck]:
    """Each enabled tolerance as a ToleranceCheck; ``rows`` come from :func:`metric_deltas`.

    Metric tolerances bound the drop from float (float - quantised <= the limit :func:`judged_limits` applies):
    doing better than float never fails.
    """
    checks: list[ToleranceCheck] = []
    limits = judged_limits(tolerances, ks, rows[0].n_queries if rows else 1, sequences=sequences)
    for (metric, strategy, k), applied in limits.items():
        row = find_row(rows, strategy, k)
        assert row is not None and row.delta is not None  # metric_deltas: every readout, with its float values
        value, limit = 0.0 - row.delta.get(metric), tolerances[metric]
        assert limit is not None  # judged_limits: the tolerances that are on
        what = f"{metric} drop, {strategy} k={k}"
        checks.append(ToleranceCheck(metric, what, value, limit, applied, bool(value <= applied + 1e-12)))
    for name, what, value, at_least in (
        ("winner_agreement", "steps with the float winner", spike.winner_agreement, True),
        ("top1_agreement", "W+Prob k=1 top-1 agreement", decision.top1_agreement[SEQUENCE_STRATEGY], True),
        ("saturations", "saturation events on the queries", spike.saturations, False),
    ):
        if (limit := tolerances[name]) is not None:
            passed = value >= limit if at_least else value <= limit
            checks.append(ToleranceCheck(name, what, value, limit, limit, bool(passed)))
    return checks


def weight_histograms(float_weights: np.ndarray, per_neuron: bool, bins: int = 64) -> WeightHistogram:
    """Histogram of the float weights divided by their scale range (per-neuron or global maximum)."""
    w = np.asarray(float_weights, dtype=np.float64)
    top = w.max(axis=0, keepdims=True) if per_neuron else np.array([[w.max()]])
    ratio = w / np.where(top > 0, top, 1.0)
    counts, edges = np.histogram(ratio, bins=bins, range=(0.0, 1.0))
    return WeightHistogram(
        "per-neuron maximum" if per_neuron else "global maximum",
        tuple(int(c) for c in counts),
        tuple(round(float(e), 6) for e in edges),
    )


def level_histogram(model: FixedPointModel) -> LevelHistogram:
    """How many weights sit on each mantissa level 0 .. 2**bits - 1."""
    levels = (1 << model.bits) - 1
    counts = np.bincount(np.asarray(model.weight_mantissa).ravel().astype(np.int64), minlength=levels + 1)
    return LevelHistogram(levels, tuple(int(c) for c in counts[: levels + 1]), float(counts[0] / max(counts.sum(), 1)))
