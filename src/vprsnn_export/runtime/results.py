"""The typed results of `vprsnn-export verify`, and their JSON form (report.json, schema ``vprsnn-verify-report/1``).

Every result is a frozen dataclass with ``to_dict()`` (the JSON value report.json holds)
and ``from_dict()`` (its inverse: ``Type.from_dict(x.to_dict()) == x``). The report
renderer and the commands read attributes, never nested string keys.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from vprsnn_export.errors import VprError
from vprsnn_export.export.model import QuantisationReport
from vprsnn_export.stats import MeanStd

SCHEMA = "vprsnn-verify-report/1"
METRICS = ("accuracy", "p_at_100r", "r_at_100p", "auc_pr")


class ReportError(VprError):
    """A missing or malformed report.json."""


def _float_or_none(value: Any) -> float | None:
    return None if value is None else float(value)


def _int_or_none(value: Any) -> int | None:
    return None if value is None else int(value)


# ---------------------------------------------------------------------------- metric level


@dataclass(frozen=True)
class MetricValues:
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

    def minus(self, other: MetricValues) -> MetricValues:
        """self - other, metric by metric."""
        return MetricValues(*(self.get(m) - other.get(m) for m in METRICS))

    def to_dict(self) -> dict[str, float]:
        return {m: self.get(m) for m in METRICS}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> MetricValues:
        return cls(*(float(data[m]) for m in METRICS))


@dataclass(frozen=True)
class MetricRow:
    """One readout (strategy at k) of one network; quantised rows carry the float values and the deltas."""

    strategy: str
    k: int
    values: MetricValues
    n_queries: int
    float_values: MetricValues | None = None
    delta: MetricValues | None = None  # quantised - float

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
        """This row with the float row's values and the differences (this - float)."""
        return MetricRow(
            self.strategy, self.k, self.values, self.n_queries, base.values, self.values.minus(base.values)
        )

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {"strategy": self.strategy, "k": self.k, **self.values.to_dict()}
        data["n_queries"] = self.n_queries
        if self.float_values is not None:
            data["float"] = self.float_values.to_dict()
        if self.delta is not None:
            data["delta"] = self.delta.to_dict()
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> MetricRow:
        return cls(
            strategy=str(data["strategy"]),
            k=int(data["k"]),
            values=MetricValues.from_dict(data),
            n_queries=int(data["n_queries"]),
            float_values=MetricValues.from_dict(data["float"]) if "float" in data else None,
            delta=MetricValues.from_dict(data["delta"]) if "delta" in data else None,
        )


def find_row(rows: Sequence[MetricRow], strategy: str, k: int) -> MetricRow | None:
    """The row of ``strategy`` at ``k``, or None."""
    return next((r for r in rows if r.strategy == strategy and r.k == k), None)


@dataclass(frozen=True)
class ToleranceCheck:
    """One enabled tolerance: the value, the limit set and the limit applied, and the verdict."""

    check: str
    what: str
    value: float
    limit: float
    applied_limit: float
    passed: bool

    def to_dict(self) -> dict[str, Any]:
        return {
            "check": self.check,
            "what": self.what,
            "value": self.value,
            "limit": self.limit,
            "applied_limit": self.applied_limit,
            "passed": self.passed,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ToleranceCheck:
        return cls(
            check=str(data["check"]),
            what=str(data["what"]),
            value=data["value"],
            limit=data["limit"],
            applied_limit=data.get("applied_limit", data["limit"]),
            passed=bool(data["passed"]),
        )


# ---------------------------------------------------------------------------- spike and decision level


@dataclass(frozen=True)
class SpikeLevel:
    """Float vs quantised spikes on the same input: winner agreement, count correlation, totals, saturations."""

    winner_agreement: float
    winner_agreement_active: float
    n_steps: int
    n_active_steps: int
    count_correlation_mean: float
    count_correlation_min: float
    count_correlation: tuple[float, ...]
    total_spikes_float: int
    total_spikes: int
    spike_ratio: float | None
    spikes_per_query_float: tuple[int, ...]
    spikes_per_query: tuple[int, ...]
    saturations: int
    calibration_saturations: int | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "winner_agreement": self.winner_agreement,
            "winner_agreement_active": self.winner_agreement_active,
            "n_steps": self.n_steps,
            "n_active_steps": self.n_active_steps,
            "count_correlation_mean": self.count_correlation_mean,
            "count_correlation_min": self.count_correlation_min,
            "count_correlation": list(self.count_correlation),
            "total_spikes_float": self.total_spikes_float,
            "total_spikes": self.total_spikes,
            "spike_ratio": self.spike_ratio,
            "spikes_per_query_float": list(self.spikes_per_query_float),
            "spikes_per_query": list(self.spikes_per_query),
            "saturations": self.saturations,
            "calibration_saturations": self.calibration_saturations,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SpikeLevel:
        return cls(
            winner_agreement=float(data["winner_agreement"]),
            winner_agreement_active=float(data["winner_agreement_active"]),
            n_steps=int(data["n_steps"]),
            n_active_steps=int(data["n_active_steps"]),
            count_correlation_mean=float(data["count_correlation_mean"]),
            count_correlation_min=float(data["count_correlation_min"]),
            count_correlation=tuple(float(v) for v in data["count_correlation"]),
            total_spikes_float=int(data["total_spikes_float"]),
            total_spikes=int(data["total_spikes"]),
            spike_ratio=_float_or_none(data["spike_ratio"]),
            spikes_per_query_float=tuple(int(v) for v in data["spikes_per_query_float"]),
            spikes_per_query=tuple(int(v) for v in data["spikes_per_query"]),
            saturations=int(data["saturations"]),
            calibration_saturations=_int_or_none(data.get("calibration_saturations")),
        )


@dataclass(frozen=True)
class DecisionLevel:
    """Float vs quantised decisions: top-1 agreement per strategy, W+Prob TV distance, aggregated agreement."""

    top1_agreement: Mapping[str, float]
    wprob_tv_mean: float
    wprob_tv_max: float
    wprob_tv: tuple[float, ...]
    aggregated_agreement: Mapping[int, float]  # k -> agreement of the k-frame aggregated W+Prob decisions

    def to_dict(self) -> dict[str, Any]:
        return {
            "top1_agreement": dict(self.top1_agreement),
            "wprob_tv_mean": self.wprob_tv_mean,
            "wprob_tv_max": self.wprob_tv_max,
            "wprob_tv": list(self.wprob_tv),
            "aggregated_agreement": {str(k): v for k, v in self.aggregated_agreement.items()},
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> DecisionLevel:
        return cls(
            top1_agreement={str(s): float(v) for s, v in data["top1_agreement"].items()},
            wprob_tv_mean=float(data["wprob_tv_mean"]),
            wprob_tv_max=float(data["wprob_tv_max"]),
            wprob_tv=tuple(float(v) for v in data["wprob_tv"]),
            aggregated_agreement={int(k): float(v) for k, v in data["aggregated_agreement"].items()},
        )


# ---------------------------------------------------------------------------- cross-implementation


@dataclass(frozen=True)
class Comparison:
    """One comparison of two implementations' outputs (``kind`` says how: "exact" or a bound).

    ``family`` is what was compared: "array" (element by element), "distribution"
    (W+Prob: identical decisions, |diff| bounded) or "config" (equal or not).
    """

    check: str
    a: str
    b: str
    kind: str
    equal: bool
    detail: str
    n_differences: int | None = None
    n_elements: int | None = None
    first_difference: tuple[int, ...] | None = None
    max_abs_difference: float | None = None
    family: str = "array"

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {"check": self.check, "a": self.a, "b": self.b, "kind": self.kind, "equal": self.equal}
        if self.family == "array":
            data["n_elements"] = self.n_elements
            data["n_differences"] = self.n_differences
            data["first_difference"] = None if self.first_difference is None else list(self.first_difference)
        elif self.family == "distribution":
            data["max_abs_difference"] = self.max_abs_difference
            data["n_differences"] = self.n_differences
        else:
            data["n_differences"] = self.n_differences
        data["detail"] = self.detail
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Comparison:
        family = "distribution" if "max_abs_difference" in data else "array" if "n_elements" in data else "config"
        first = data.get("first_difference")
        return cls(
            check=str(data["check"]),
            a=str(data["a"]),
            b=str(data["b"]),
            kind=str(data["kind"]),
            equal=bool(data["equal"]),
            detail=str(data["detail"]),
            n_differences=_int_or_none(data.get("n_differences")),
            n_elements=_int_or_none(data.get("n_elements")),
            first_difference=None if first is None else tuple(int(i) for i in first),
            max_abs_difference=_float_or_none(data.get("max_abs_difference")),
            family=family,
        )


@dataclass(frozen=True)
class ConformanceResult:
    """Every cross-implementation comparison of one fixed-point model, the targets skipped and the files written."""

    comparisons: tuple[Comparison, ...]
    reference_queries: int
    skipped: Mapping[str, str] = field(default_factory=dict)
    files: Mapping[str, tuple[str, ...]] = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return all(c.equal for c in self.comparisons)

    @property
    def n_checks(self) -> int:
        return len(self.comparisons)

    @property
    def n_failed(self) -> int:
        return sum(not c.equal for c in self.comparisons)

    @property
    def failures(self) -> tuple[Comparison, ...]:
        return tuple(c for c in self.comparisons if not c.equal)

    def with_files(self, name: str, paths: Sequence[str]) -> ConformanceResult:
        """This result with one more entry in ``files``."""
        return ConformanceResult(
            self.comparisons, self.reference_queries, self.skipped, {**self.files, name: tuple(paths)}
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "checks": [c.to_dict() for c in self.comparisons],
            "passed": self.passed,
            "n_checks": self.n_checks,
            "n_failed": self.n_failed,
            "reference_queries": self.reference_queries,
            "skipped": dict(self.skipped),
            "files": {name: list(paths) for name, paths in self.files.items()},
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ConformanceResult:
        return cls(
            comparisons=tuple(Comparison.from_dict(c) for c in data["checks"]),
            reference_queries=int(data["reference_queries"]),
            skipped={str(k): str(v) for k, v in data.get("skipped", {}).items()},
            files={str(k): tuple(str(p) for p in v) for k, v in data.get("files", {}).items()},
        )


# ---------------------------------------------------------------------------- curves and histograms


@dataclass(frozen=True)
class PrCurve:
    """The exact precision-recall operating points of one score matrix."""

    precision: tuple[float, ...]
    recall: tuple[float, ...]

    def to_dict(self) -> dict[str, list[float]]:
        return {"precision": list(self.precision), "recall": list(self.recall)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> PrCurve:
        return cls(tuple(float(p) for p in data["precision"]), tuple(float(r) for r in data["recall"]))


def _curves_to_dict(curves: Mapping[str, PrCurve]) -> dict[str, Any]:
    return {name: curve.to_dict() for name, curve in curves.items()}


def _curves_from_dict(data: Mapping[str, Any]) -> dict[str, PrCurve]:
    return {str(name): PrCurve.from_dict(curve) for name, curve in data.items()}


@dataclass(frozen=True)
class WeightHistogram:
    """Histogram of the float weights divided by their scale range."""

    normalised_by: str
    counts: tuple[int, ...]
    edges: tuple[float, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"normalised_by": self.normalised_by, "counts": list(self.counts), "edges": list(self.edges)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> WeightHistogram:
        return cls(
            str(data["normalised_by"]), tuple(int(c) for c in data["counts"]), tuple(float(e) for e in data["edges"])
        )


@dataclass(frozen=True)
class LevelHistogram:
    """How many weights sit on each mantissa level 0 .. levels."""

    levels: int
    counts: tuple[int, ...]
    zero_fraction: float

    def to_dict(self) -> dict[str, Any]:
        return {"levels": self.levels, "counts": list(self.counts), "zero_fraction": self.zero_fraction}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> LevelHistogram:
        return cls(int(data["levels"]), tuple(int(c) for c in data["counts"]), float(data["zero_fraction"]))


# ---------------------------------------------------------------------------- modules of an ensemble


@dataclass(frozen=True)
class ModuleRow:
    """One module of an ensemble at one bit width, against the float ensemble on the same queries.

    Accuracies are the **whole-route** W+Prob decisions (every module's neurons, every place)
    scored on the queries whose true place lies in this module's region, at k=1 and at the
    largest k; ``winner_agreement`` is the share of (query, step) pairs on which this module's
    WTA picks the same winner as the float module (or both stay silent), over all queries.
    """

    module: int
    first_place: int  # place id of the region's first place
    last_place: int  # place id of its last place
    n_queries: int  # queries whose true place lies in the region
    k: int  # the largest k of the run
    float_accuracy: float  # k = 1
    accuracy: float
    float_accuracy_k: float  # at k
    accuracy_k: float
    winner_agreement: float
    spikes_float: int  # this module's output spikes over all queries
    spikes: int

    @property
    def delta_k(self) -> float:
        """Accuracy at the largest k, quantised minus float."""
        return self.accuracy_k - self.float_accuracy_k

    def to_dict(self) -> dict[str, Any]:
        return {
            "module": self.module,
            "first_place": self.first_place,
            "last_place": self.last_place,
            "n_queries": self.n_queries,
            "k": self.k,
            "float_accuracy": self.float_accuracy,
            "accuracy": self.accuracy,
            "float_accuracy_k": self.float_accuracy_k,
            "accuracy_k": self.accuracy_k,
            "winner_agreement": self.winner_agreement,
            "spikes_float": self.spikes_float,
            "spikes": self.spikes,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ModuleRow:
        return cls(
            module=int(data["module"]),
            first_place=int(data["first_place"]),
            last_place=int(data["last_place"]),
            n_queries=int(data["n_queries"]),
            k=int(data["k"]),
            float_accuracy=float(data["float_accuracy"]),
            accuracy=float(data["accuracy"]),
            float_accuracy_k=float(data["float_accuracy_k"]),
            accuracy_k=float(data["accuracy_k"]),
            winner_agreement=float(data["winner_agreement"]),
            spikes_float=int(data["spikes_float"]),
            spikes=int(data["spikes"]),
        )


# ---------------------------------------------------------------------------- one network


@dataclass(frozen=True)
class BitsResult:
    """Every check of one network at one weight bit width."""

    bits: int
    quantisation: QuantisationReport
    cross_implementation: ConformanceResult
    spike_level: SpikeLevel
    decision_level: DecisionLevel
    metrics: tuple[MetricRow, ...]
    tolerance_checks: tuple[ToleranceCheck, ...]
    pr_curves: Mapping[str, PrCurve]
    weight_levels: LevelHistogram
    passed: bool
    seconds: Mapping[str, float] = field(default_factory=dict)
    modules: tuple[ModuleRow, ...] = ()  # an ensemble's modules (empty for one network)

    def row(self, strategy: str, k: int) -> MetricRow:
        row = find_row(self.metrics, strategy, k)
        if row is None:
            raise KeyError(f"no metric row {strategy} k={k}")
        return row

    def to_dict(self) -> dict[str, Any]:
        return {
            "bits": self.bits,
            "quantisation": self.quantisation.to_dict(),
            "cross_implementation": self.cross_implementation.to_dict(),
            "spike_level": self.spike_level.to_dict(),
            "decision_level": self.decision_level.to_dict(),
            "metrics": [r.to_dict() for r in self.metrics],
            "tolerance_checks": [c.to_dict() for c in self.tolerance_checks],
            "pr_curves": _curves_to_dict(self.pr_curves),
            "weight_levels": self.weight_levels.to_dict(),
            "passed": self.passed,
            "seconds": dict(self.seconds),
            "modules": [m.to_dict() for m in self.modules],
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> BitsResult:
        return cls(
            bits=int(data["bits"]),
            quantisation=QuantisationReport.from_dict(data["quantisation"]),
            cross_implementation=ConformanceResult.from_dict(data["cross_implementation"]),
            spike_level=SpikeLevel.from_dict(data["spike_level"]),
            decision_level=DecisionLevel.from_dict(data["decision_level"]),
            metrics=tuple(MetricRow.from_dict(r) for r in data["metrics"]),
            tolerance_checks=tuple(ToleranceCheck.from_dict(c) for c in data["tolerance_checks"]),
            pr_curves=_curves_from_dict(data["pr_curves"]),
            weight_levels=LevelHistogram.from_dict(data["weight_levels"]),
            passed=bool(data["passed"]),
            seconds={str(k): float(v) for k, v in data.get("seconds", {}).items()},
            modules=tuple(ModuleRow.from_dict(m) for m in data.get("modules", [])),
        )


@dataclass(frozen=True)
class FloatResult:
    """The float network on the same queries: its metrics, spikes, PR curves and weight histogram."""

    metrics: tuple[MetricRow, ...]
    total_spikes: int
    pr_curves: Mapping[str, PrCurve]
    weights: WeightHistogram

    def to_dict(self) -> dict[str, Any]:
        return {
            "metrics": [r.to_dict() for r in self.metrics],
            "total_spikes": self.total_spikes,
            "pr_curves": _curves_to_dict(self.pr_curves),
            "weights": self.weights.to_dict(),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> FloatResult:
        return cls(
            metrics=tuple(MetricRow.from_dict(r) for r in data["metrics"]),
            total_spikes=int(data["total_spikes"]),
            pr_curves=_curves_from_dict(data["pr_curves"]),
            weights=WeightHistogram.from_dict(data["weights"]),
        )


@dataclass(frozen=True)
class VerifiedRun:
    """One verified network (one checkpoint): the float reference and every bit width."""

    label: str | None
    seed: int | None
    config: Mapping[str, Any]
    checkpoint_sha256: str
    checkpoint_data: Mapping[str, Any]
    query: str
    n_queries: int
    query_place_ids: tuple[int, ...]
    reference_place_ids: tuple[int, ...]
    export_dir: str | None
    float: FloatResult
    bits: tuple[BitsResult, ...]
    checkpoint: str | None = None  # the checkpoint file, when the caller names it
    recorded_queries: int | None = None  # queries of the step-level checks (None: all; runtime.verify.RASTER_BUDGET)

    @property
    def passed(self) -> bool:
        return all(r.passed for r in self.bits)

    @property
    def ks(self) -> list[int]:
        return sorted({row.k for row in self.float.metrics})

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {
            "label": self.label,
            "seed": self.seed,
            "config": dict(self.config),
            "checkpoint_sha256": self.checkpoint_sha256,
            "checkpoint_data": dict(self.checkpoint_data),
            "query": self.query,
            "n_queries": self.n_queries,
            "query_place_ids": list(self.query_place_ids),
            "reference_place_ids": list(self.reference_place_ids),
            "export_dir": self.export_dir,
            "float": self.float.to_dict(),
            "bits": [r.to_dict() for r in self.bits],
            "passed": self.passed,
        }
        if self.checkpoint is not None:
            data["checkpoint"] = self.checkpoint
        if self.recorded_queries is not None:
            data["recorded_queries"] = self.recorded_queries
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> VerifiedRun:
        return cls(
            label=data.get("label"),
            seed=_int_or_none(data.get("seed")),
            config=dict(data.get("config", {})),
            checkpoint_sha256=str(data.get("checkpoint_sha256", "")),
            checkpoint_data=dict(data.get("checkpoint_data", {})),
            query=str(data["query"]),
            n_queries=int(data["n_queries"]),
            query_place_ids=tuple(int(p) for p in data.get("query_place_ids", [])),
            reference_place_ids=tuple(int(p) for p in data.get("reference_place_ids", [])),
            export_dir=data.get("export_dir"),
            float=FloatResult.from_dict(data["float"]),
            bits=tuple(BitsResult.from_dict(r) for r in data["bits"]),
            checkpoint=data.get("checkpoint"),
            recorded_queries=_int_or_none(data.get("recorded_queries")),
        )


# ---------------------------------------------------------------------------- over networks


def _ms_dict(values: Mapping[Any, MeanStd]) -> dict[str, Any]:
    return {str(k): v.to_dict() for k, v in values.items()}


@dataclass(frozen=True)
class SummaryRow:
    """Mean ± std over networks of one readout's metrics (and of their deltas, for quantised rows)."""

    strategy: str
    k: int
    values: Mapping[str, MeanStd]
    delta: Mapping[str, MeanStd] | None = None

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {"strategy": self.strategy, "k": self.k, **_ms_dict(self.values)}
        if self.delta is not None:
            data["delta"] = _ms_dict(self.delta)
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SummaryRow:
        return cls(
            strategy=str(data["strategy"]),
            k=int(data["k"]),
            values={m: MeanStd.from_dict(data[m]) for m in METRICS},
            delta={m: MeanStd.from_dict(data["delta"][m]) for m in METRICS} if "delta" in data else None,
        )


@dataclass(frozen=True)
class BitsSummary:
    """Mean ± std over networks of every measurement at one bit width."""

    bits: int
    n_runs: int
    n_passed: int
    cross_implementation_passed: int
    metrics: tuple[SummaryRow, ...]
    winner_agreement: MeanStd
    count_correlation: MeanStd
    spike_ratio: MeanStd
    saturations: MeanStd
    top1_agreement: Mapping[str, MeanStd]
    wprob_tv_mean: MeanStd
    aggregated_agreement: Mapping[int, MeanStd]

    def row(self, strategy: str, k: int) -> SummaryRow | None:
        return next((r for r in self.metrics if r.strategy == strategy and r.k == k), None)

    def to_dict(self) -> dict[str, Any]:
        return {
            "bits": self.bits,
            "n_runs": self.n_runs,
            "n_passed": self.n_passed,
            "cross_implementation_passed": self.cross_implementation_passed,
            "metrics": [r.to_dict() for r in self.metrics],
            "winner_agreement": self.winner_agreement.to_dict(),
            "count_correlation": self.count_correlation.to_dict(),
            "spike_ratio": self.spike_ratio.to_dict(),
            "saturations": self.saturations.to_dict(),
            "top1_agreement": _ms_dict(self.top1_agreement),
            "wprob_tv_mean": self.wprob_tv_mean.to_dict(),
            "aggregated_agreement": _ms_dict(self.aggregated_agreement),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> BitsSummary:
        return cls(
            bits=int(data["bits"]),
            n_runs=int(data["n_runs"]),
            n_passed=int(data["n_passed"]),
            cross_implementation_passed=int(data["cross_implementation_passed"]),
            metrics=tuple(SummaryRow.from_dict(r) for r in data["metrics"]),
            winner_agreement=MeanStd.from_dict(data["winner_agreement"]),
            count_correlation=MeanStd.from_dict(data["count_correlation"]),
            spike_ratio=MeanStd.from_dict(data["spike_ratio"]),
            saturations=MeanStd.from_dict(data["saturations"]),
            top1_agreement={str(s): MeanStd.from_dict(v) for s, v in data["top1_agreement"].items()},
            wprob_tv_mean=MeanStd.from_dict(data["wprob_tv_mean"]),
            aggregated_agreement={int(k): MeanStd.from_dict(v) for k, v in data["aggregated_agreement"].items()},
        )


@dataclass(frozen=True)
class RunSummary:
    """Mean ± std over runs (independently trained networks) of the float metrics and of each bit width."""

    n_runs: int
    float: tuple[SummaryRow, ...]
    bits: tuple[BitsSummary, ...]
    passed: bool

    def to_dict(self) -> dict[str, Any]:
        return {
            "n_runs": self.n_runs,
            "float": [r.to_dict() for r in self.float],
            "bits": [b.to_dict() for b in self.bits],
            "passed": self.passed,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> RunSummary:
        return cls(
            n_runs=int(data["n_runs"]),
            float=tuple(SummaryRow.from_dict(r) for r in data["float"]),
            bits=tuple(BitsSummary.from_dict(b) for b in data["bits"]),
            passed=bool(data["passed"]),
        )


@dataclass(frozen=True)
class VerifyReport:
    """The whole report.json: settings, versions, every run, the summary and the verdict."""

    created: str
    command: tuple[str, ...] | None
    seconds: float | None
    versions: Mapping[str, str]
    settings: Mapping[str, Any]
    runs: tuple[VerifiedRun, ...]
    summary: RunSummary
    combined_from: tuple[str, ...] | None = None  # combined reports only: their files,
    commands: tuple[tuple[str, ...] | None, ...] | None = None  # their commands,
    settings_differ: tuple[str, ...] | None = None  # and the settings on which they differ

    @property
    def passed(self) -> bool:
        return all(r.passed for r in self.runs)

    @property
    def n_passed(self) -> int:
        return sum(r.passed for r in self.runs)

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {
            "schema": SCHEMA,
            "created": self.created,
            "command": None if self.command is None else list(self.command),
            "seconds": self.seconds,
            "versions": dict(self.versions),
            "settings": dict(self.settings),
            "runs": [r.to_dict() for r in self.runs],
            "summary": self.summary.to_dict(),
            "passed": self.passed,
        }
        if self.combined_from is not None:
            data["combined_from"] = list(self.combined_from)
        if self.commands is not None:
            data["commands"] = [None if c is None else list(c) for c in self.commands]
        if self.settings_differ is not None:
            data["settings_differ"] = list(self.settings_differ)
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str = "report.json") -> VerifyReport:
        """The report of a report.json's content; ReportError naming ``source`` when it is not one."""
        if not isinstance(data, Mapping) or data.get("schema") != SCHEMA:
            found = data.get("schema") if isinstance(data, Mapping) else type(data).__name__
            raise ReportError(f"not a verify report (schema {found!r}, expected {SCHEMA!r})", source)
        if not isinstance(data.get("runs"), list) or not data["runs"]:
            raise ReportError("the report holds no runs", source)
        try:
            commands = data.get("commands")
            report = cls(
                created=str(data.get("created", "?")),
                command=None if data.get("command") is None else tuple(data["command"]),
                seconds=_float_or_none(data.get("seconds")),
                versions={str(k): str(v) for k, v in data.get("versions", {}).items()},
                settings=dict(data.get("settings", {})),
                runs=tuple(VerifiedRun.from_dict(r) for r in data["runs"]),
                summary=RunSummary.from_dict(data["summary"]),
                combined_from=None if data.get("combined_from") is None else tuple(data["combined_from"]),
                commands=None if commands is None else tuple(None if c is None else tuple(c) for c in commands),
                settings_differ=None if data.get("settings_differ") is None else tuple(data["settings_differ"]),
            )
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ReportError(f"malformed verify report ({type(exc).__name__}: {exc})", source) from None
        if any(not run.bits for run in report.runs):
            raise ReportError("a run of the report holds no bit widths", source)
        if data.get("passed") is not report.passed:
            raise ReportError(
                f"the stored verdict passed={data.get('passed')!r} does not match the report's checks", source
            )
        return report


__all__ = [
    "METRICS",
    "SCHEMA",
    "BitsResult",
    "BitsSummary",
    "Comparison",
    "ConformanceResult",
    "DecisionLevel",
    "FloatResult",
    "LevelHistogram",
    "MetricRow",
    "MetricValues",
    "PrCurve",
    "ReportError",
    "RunSummary",
    "SpikeLevel",
    "SummaryRow",
    "ToleranceCheck",
    "VerifiedRun",
    "VerifyReport",
    "WeightHistogram",
    "find_row",
]
