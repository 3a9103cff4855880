"""The typed results of `vprsnn-export verify`, and their JSON form (report.json, schema ``vprsnn-verify-report/1``).

Every result is a frozen dataclass with ``to_dict()`` (the JSON value report.json holds)
and ``from_dict()`` (its inverse: ``Type.from_dict(x.to_dict()) == x``), both by the one
generic mapping of :mod:`vprsnn_export.io.serial` from the fields and their type hints; a
field's options (``json_options``) keep the schema's keys and load older files. The report
renderer and the commands read attributes, never nested string keys.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

from vprsnn_export.errors import VprError
from vprsnn_export.export.model import SUPPORTED_BITS, QuantisationReport
from vprsnn_export.io.serial import READ_ERRORS, JsonDataclass, describe, from_json_dict, json_options
from vprsnn_export.network.cost import CostSummary
from vprsnn_export.readout.metrics import METRICS, MetricRow, MetricValues, find_row
from vprsnn_export.stats import MeanStd

SCHEMA = "vprsnn-verify-report/1"


class ReportError(VprError):
    """A missing or malformed report.json."""


# ---------------------------------------------------------------------------- metric level (readout.metrics)


@dataclass(frozen=True)
class ToleranceCheck(JsonDataclass):
    """One enabled tolerance: the value, the limit set and the limit applied, and the verdict."""

    check: str
    what: str
    value: float
    limit: float
    applied_limit: float = field(
        metadata=json_options(missing_from=lambda data: data["limit"])
    )  # older files: the limit set
    passed: bool


@dataclass(frozen=True)
class PairedCheck(JsonDataclass):
    """One metric of one readout (strategy at k), float vs deployed on the same queries, judged as a pair.

    ``float_right_deployed_wrong`` (b) and ``float_wrong_deployed_right`` (c) are the per-query flips of
    correctness; ``difference`` is deployed - float; [``low``, ``high``] its paired interval at the report's
    confidence level (``method``: exact McNemar for accuracy at k=1, the paired bootstrap otherwise, in
    blocks of k queries for k > 1); ``limit`` the drop limit applied (None: the metric has no tolerance
    there, reported only). ``verdict``: holds / fails / undecided / not judged (readout/paired.py), None
    when unchecked; ``queries_to_decide``: for an undecided check, roughly how many queries would decide it.
    """

    strategy: str
    k: int
    metric: str
    n_queries: int
    float_right_deployed_wrong: int
    float_wrong_deployed_right: int
    float_value: float
    difference: float
    low: float
    high: float
    method: str
    p_value: float | None = field(default=None, metadata=json_options(omit="none"))  # exact McNemar, k=1 accuracy
    limit: float | None = None
    verdict: str | None = None
    queries_to_decide: int | None = field(default=None, metadata=json_options(omit="none"))
    note: str | None = field(default=None, metadata=json_options(omit="none"))


#: The verdicts of a bit width (and of a run or report): the worst of its checks, in this order.
VERDICTS = ("fails", "undecided", "holds")


def worst_verdict(verdicts: Iterable[str]) -> str:
    """The worst of several verdicts (fails > undecided > holds); holds when there are none."""
    found = set(verdicts)
    return next((v for v in VERDICTS if v in found), "holds")


# ---------------------------------------------------------------------------- spike and decision level


@dataclass(frozen=True)
class SpikeLevel(JsonDataclass):
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
    calibration_saturations: int | None = None  # older files: None


@dataclass(frozen=True)
class DecisionLevel(JsonDataclass):
    """Float vs quantised decisions: top-1 agreement per strategy, W+Prob TV distance, aggregated agreement."""

    top1_agreement: Mapping[str, float]
    wprob_tv_mean: float
    wprob_tv_max: float
    wprob_tv: tuple[float, ...]
    aggregated_agreement: Mapping[int, float]  # k -> agreement of the k-frame aggregated W+Prob decisions


# ---------------------------------------------------------------------------- cross-implementation


@dataclass(frozen=True)
class Comparison(JsonDataclass):
    """One comparison of two implementations' outputs (``kind`` says how: "exact" or a bound).

    ``family`` is what was compared: "array" (element by element), "distribution"
    (W+Prob: identical decisions, |diff| bounded) or "config" (equal or not). ``equal`` says the
    outputs are identical. A **tolerance row** (``tolerance`` set: a float consumer's decisions must
    agree on at least that share of the ``n_elements`` decisions) passes within its tolerance while
    ``n_differences`` decisions differ; it is never counted as exact.
    """

    check: str
    a: str
    b: str
    kind: str
    equal: bool
    detail: str
    n_differences: int | None = None
    n_elements: int | None = field(
        default=None, metadata=json_options(omit=lambda c: c.family != "array" and c.tolerance is None)
    )
    first_difference: tuple[int, ...] | None = field(
        default=None, metadata=json_options(omit=lambda c: c.family != "array")
    )
    max_abs_difference: float | None = field(
        default=None, metadata=json_options(omit=lambda c: c.family != "distribution")
    )
    family: str = field(default="array", metadata=json_options(write=False, missing_from=lambda data: _family(data)))
    tolerance: float | None = field(
        default=None, metadata=json_options(omit="none", missing_from=lambda data: _stated_tolerance(data))
    )

    # the keys each family writes, in this order
    __json_extra__ = ("passed",)
    __json_order__: ClassVar[tuple[str, ...]] = (
        *("check", "a", "b", "kind", "equal", "tolerance", "passed", "n_elements", "max_abs_difference"),
        *("n_differences", "first_difference", "detail"),
    )

    @property
    def passed(self) -> bool:
        """Exact rows: identical. Tolerance rows: the agreeing share 1 - n_differences / n_elements reaches the
        tolerance (a row that compared nothing, a consumer refusing the file, is not gated)."""
        if self.tolerance is None:
            return self.equal
        if not self.n_elements:
            return True
        return 1.0 - (self.n_differences or 0) / self.n_elements >= self.tolerance - 1e-12

    @property
    def difference(self) -> float | None:
        """A tolerance row's measured difference: the share of decisions that differ (None when none compared)."""
        return None if not self.n_elements else (self.n_differences or 0) / self.n_elements


def _family(data: Mapping[str, Any]) -> str:
    """A comparison's family, from the keys its JSON object holds."""
    return "distribution" if "max_abs_difference" in data else "array" if "n_elements" in data else "config"


def _stated_tolerance(data: Mapping[str, Any]) -> float | None:
    """An older file's tolerance row: its kind ``decision agreement >= 95.0%`` (exact rows: None)."""
    match = re.fullmatch(r"decision agreement >= ([0-9.]+)%", str(data.get("kind", "")))
    return None if match is None else float(match.group(1)) / 100


@dataclass(frozen=True)
class ConformanceResult(JsonDataclass):
    """Every cross-implementation comparison of one fixed-point model, the targets skipped and the files written."""

    comparisons: tuple[Comparison, ...] = field(metadata=json_options(key="checks"))
    reference_queries: int
    skipped: Mapping[str, str] = field(default_factory=dict)
    files: Mapping[str, tuple[str, ...]] = field(default_factory=dict)

    __json_extra__ = ("passed", "n_checks", "n_failed", "n_exact", "n_identical", "n_tolerance", "n_within_tolerance")
    __json_order__ = ("checks", *__json_extra__, "reference_queries", "skipped", "files")

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.comparisons)

    @property
    def n_checks(self) -> int:
        return len(self.comparisons)

    @property
    def n_failed(self) -> int:
        return sum(not c.passed for c in self.comparisons)

    @property
    def exact(self) -> tuple[Comparison, ...]:
        """The exact rows (any difference fails)."""
        return tuple(c for c in self.comparisons if c.tolerance is None)

    @property
    def tolerance_rows(self) -> tuple[Comparison, ...]:
        """The rows judged within a stated tolerance (the float NIR consumers' decisions)."""
        return tuple(c for c in self.comparisons if c.tolerance is not None)

    @property
    def n_exact(self) -> int:
        return len(self.exact)

    @property
    def n_identical(self) -> int:
        """Exact rows whose outputs are identical."""
        return sum(c.equal for c in self.exact)

    @property
    def n_tolerance(self) -> int:
        return len(self.tolerance_rows)

    @property
    def n_within_tolerance(self) -> int:
        return sum(c.passed for c in self.tolerance_rows)

    @property
    def failures(self) -> tuple[Comparison, ...]:
        return tuple(c for c in self.comparisons if not c.passed)

    def with_files(self, name: str, paths: Sequence[str]) -> ConformanceResult:
        """This result with one more entry in ``files``."""
        return ConformanceResult(
            self.comparisons, self.reference_queries, self.skipped, {**self.files, name: tuple(paths)}
        )


# ---------------------------------------------------------------------------- curves and histograms


@dataclass(frozen=True)
class PrCurve(JsonDataclass):
    """The exact precision-recall operating points of one score matrix."""

    precision: tuple[float, ...]
    recall: tuple[float, ...]


@dataclass(frozen=True)
class WeightHistogram(JsonDataclass):
    """Histogram of the float weights divided by their scale range."""

    normalised_by: str
    counts: tuple[int, ...]
    edges: tuple[float, ...]


@dataclass(frozen=True)
class LevelHistogram(JsonDataclass):
    """How many weights sit on each mantissa level 0 .. levels."""

    levels: int
    counts: tuple[int, ...]
    zero_fraction: float


# ---------------------------------------------------------------------------- modules of an ensemble


@dataclass(frozen=True)
class ModuleRow(JsonDataclass):
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


# ---------------------------------------------------------------------------- one network


@dataclass(frozen=True)
class BitsResult(JsonDataclass):
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
    # the paired statistics of every readout (older files: none)
    paired: tuple[PairedCheck, ...] = field(default=(), metadata=json_options(omit=lambda r: not r.paired))

    __json_extra__ = ("verdict",)

    @property
    def verdict(self) -> str:
        """fails (a check failed: cross-implementation, a non-metric limit or a paired interval outside its
        tolerance), undecided (a paired interval straddles its tolerance), else holds."""
        if not self.passed:
            return "fails"
        return worst_verdict(p.verdict for p in self.paired if p.verdict is not None)

    def row(self, strategy: str, k: int) -> MetricRow:
        row = find_row(self.metrics, strategy, k)
        if row is None:
            raise KeyError(f"no metric row {strategy} k={k}")
        return row


@dataclass(frozen=True)
class FloatResult(JsonDataclass):
    """The float network on the same queries: its metrics, spikes, PR curves and weight histogram."""

    metrics: tuple[MetricRow, ...]
    total_spikes: int
    pr_curves: Mapping[str, PrCurve]
    weights: WeightHistogram
    cost: CostSummary | None = field(default=None, metadata=json_options(omit="none"))  # events per query


@dataclass(frozen=True)
class VerifiedRun(JsonDataclass):
    """One verified network (one checkpoint): the float reference and every bit width."""

    label: str | None = field(metadata=json_options(missing=None))  # older files may lack the keys given `missing`
    seed: int | None = field(metadata=json_options(missing=None))
    config: Mapping[str, Any] = field(metadata=json_options(missing={}))
    checkpoint_sha256: str = field(metadata=json_options(missing=""))
    checkpoint_data: Mapping[str, Any] = field(metadata=json_options(missing={}))
    query: str
    n_queries: int
    query_place_ids: tuple[int, ...] = field(metadata=json_options(missing=()))
    reference_place_ids: tuple[int, ...] = field(metadata=json_options(missing=()))
    export_dir: str | None = field(metadata=json_options(missing=None))
    float: FloatResult
    bits: tuple[BitsResult, ...]
    checkpoint: str | None = field(
        default=None, metadata=json_options(omit="none")
    )  # the checkpoint file, when the caller names it
    # queries of the step-level checks (None: all; runtime.verify.run.RASTER_BUDGET)
    recorded_queries: int | None = field(default=None, metadata=json_options(omit="none"))

    __json_extra__ = ("passed", "verdict")
    __json_order__ = (
        *("label", "seed", "config", "checkpoint_sha256", "checkpoint_data", "query", "n_queries"),
        *("query_place_ids", "reference_place_ids", "export_dir", "float", "bits", "passed", "verdict"),
    )

    @property
    def passed(self) -> bool:
        return all(r.passed for r in self.bits)

    @property
    def verdict(self) -> str:
        return worst_verdict(r.verdict for r in self.bits)

    @property
    def ks(self) -> list[int]:
        return sorted({row.k for row in self.float.metrics})


# ---------------------------------------------------------------------------- over networks


@dataclass(frozen=True)
class SummaryRow(JsonDataclass):
    """Mean ± std over networks of one readout's metrics (and of their deltas, for quantised rows)."""

    strategy: str
    k: int
    values: Mapping[str, MeanStd] = field(metadata=json_options(flatten=METRICS))
    delta: Mapping[str, MeanStd] | None = field(default=None, metadata=json_options(omit="none"))


@dataclass(frozen=True)
class BitsSummary(JsonDataclass):
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
    # networks per verdict (older files: none)
    verdicts: Mapping[str, int] = field(default_factory=dict, metadata=json_options(omit=lambda b: not b.verdicts))

    def row(self, strategy: str, k: int) -> SummaryRow | None:
        return next((r for r in self.metrics if r.strategy == strategy and r.k == k), None)


@dataclass(frozen=True)
class RunSummary(JsonDataclass):
    """Mean ± std over runs (independently trained networks) of the float metrics and of each bit width."""

    n_runs: int
    float: tuple[SummaryRow, ...]
    bits: tuple[BitsSummary, ...]
    passed: bool


@dataclass(frozen=True)
class VerifyReport(JsonDataclass):
    """The whole report.json: settings, versions, every run, the summary and the verdict."""

    created: str = field(metadata=json_options(missing="?"))
    command: tuple[str, ...] | None = field(metadata=json_options(missing=None))
    seconds: float | None = field(metadata=json_options(missing=None))
    versions: Mapping[str, str] = field(metadata=json_options(missing={}))
    settings: Mapping[str, Any] = field(metadata=json_options(missing={}))
    runs: tuple[VerifiedRun, ...]
    summary: RunSummary
    # combined reports only: their files, their commands, and the settings on which they differ
    combined_from: tuple[str, ...] | None = field(default=None, metadata=json_options(omit="none"))
    commands: tuple[tuple[str, ...] | None, ...] | None = field(default=None, metadata=json_options(omit="none"))
    settings_differ: tuple[str, ...] | None = field(default=None, metadata=json_options(omit="none"))

    __json_extra__ = ("schema", "passed", "verdict")
    __json_order__ = (
        *("schema", "created", "command", "seconds", "versions", "settings", "runs", "summary", "passed"),
        "verdict",
    )

    @property
    def schema(self) -> str:
        return SCHEMA

    @property
    def passed(self) -> bool:
        return all(r.passed for r in self.runs)

    @property
    def verdict(self) -> str:
        """fails, undecided or holds: the worst verdict of every network at every bit width."""
        return worst_verdict(r.verdict for r in self.runs)

    @property
    def n_passed(self) -> int:
        return sum(r.passed for r in self.runs)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str = "report.json") -> VerifyReport:
        """The report of a report.json's content; ReportError naming ``source`` when it is not one."""
        if not isinstance(data, Mapping) or data.get("schema") != SCHEMA:
            found = data.get("schema") if isinstance(data, Mapping) else type(data).__name__
            raise ReportError(f"not a verify report (schema {found!r}, expected {SCHEMA!r})", source)
        if not isinstance(data.get("runs"), list) or not data["runs"]:
            raise ReportError("the report holds no runs", source)
        try:
            report = from_json_dict(cls, data)
        except READ_ERRORS as exc:
            raise ReportError(f"malformed verify report ({describe(exc)})", source) from None
        if any(not run.bits for run in report.runs):
            raise ReportError("a run of the report holds no bit widths", source)
        problem = _non_finite(data) or _out_of_range(report)
        if problem:
            raise ReportError(problem, source)
        if data.get("passed") is not report.passed:
            raise ReportError(
                f"the stored verdict passed={data.get('passed')!r} does not match the report's checks", source
            )
        return report


def _non_finite(data: Any, where: str = "") -> str | None:
    """The first NaN or infinite number of a parsed JSON value, as "NaN at runs[0].float"; None when all are finite."""
    stack: list[tuple[Any, str]] = [(data, where)]
    while stack:
        item, path = stack.pop()
        if isinstance(item, float) and not math.isfinite(item):
            return f"{item} at {path.lstrip('.') or 'the top'}: a report holds finite numbers only"
        if isinstance(item, Mapping):
            stack += [(value, f"{path}.{key}") for key, value in item.items()]
        elif isinstance(item, list):
            stack += [(value, f"{path}[{index}]") for index, value in enumerate(item)]
    return None


def _fractions(report: VerifyReport) -> Iterable[tuple[str, float | None]]:
    """Every stored fraction of ``report`` (metric values, accuracies, agreements) with its name; each lies in [0, 1]."""
    for run in report.runs:
        results = (("float", run.float.metrics), *((f"{r.bits} bits", r.metrics) for r in run.bits))
        for name, rows in results:
            for row in rows:
                for values in (row.values, row.float_values):
                    if values is not None:
                        yield from ((f"{name} {row.strategy} k={row.k} {m}", values.get(m)) for m in METRICS)
        for result in run.bits:
            yield from ((f"{result.bits} bits paired {p.metric} float", p.float_value) for p in result.paired)
            yield from (
                (f"{result.bits} bits module {m.module} accuracy", a)
                for m in result.modules
                for a in (m.float_accuracy, m.accuracy, m.float_accuracy_k, m.accuracy_k)
            )
            yield f"{result.bits} bits winner agreement", result.spike_level.winner_agreement
            yield from (
                (f"{result.bits} bits top-1 agreement {s}", v) for s, v in result.decision_level.top1_agreement.items()
            )
    for mean_row in (*report.summary.float, *(row for bits in report.summary.bits for row in bits.metrics)):
        yield from ((f"summary {mean_row.strategy} k={mean_row.k} {m}", v.mean) for m, v in mean_row.values.items())


def _out_of_range(report: VerifyReport) -> str | None:
    """The first stored value outside its range (a fraction outside [0, 1], a bit width the project does not
    support); None when every one lies inside."""
    widths = [r.bits for run in report.runs for r in run.bits] + [b.bits for b in report.summary.bits]
    wrong = next((b for b in widths if isinstance(b, bool) or b not in SUPPORTED_BITS), None)
    if wrong is not None:
        return f"bits {wrong!r}: supported widths are {SUPPORTED_BITS[0]} to {SUPPORTED_BITS[-1]}"
    for name, value in _fractions(report):
        if value is not None and not (isinstance(value, int | float) and 0.0 <= value <= 1.0):
            return f"{name} = {value!r}: a fraction lies in [0, 1]"
    return None


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
    "PairedCheck",
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
    "worst_verdict",
]
