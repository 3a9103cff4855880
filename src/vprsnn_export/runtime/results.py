"""The typed results of `vprsnn-export verify`, and their JSON form (report.json, schema ``vprsnn-verify-report/1``).

Every result is a frozen dataclass whose ``to_dict()`` and ``from_dict()`` (``Type.from_dict(x.to_dict()) == x``)
come from the fields by :mod:`vprsnn_export.io.serial`; field options keep the schema's keys and load older files.
The measurements held here are in :mod:`vprsnn_export.runtime.measurements`, re-exported here.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from vprsnn_export.errors import VprError
from vprsnn_export.export.model import SUPPORTED_BITS, QuantisationReport
from vprsnn_export.io.serial import READ_ERRORS, JsonDataclass, describe, from_json_dict, json_options
from vprsnn_export.network.cost import CostSummary
from vprsnn_export.readout.metrics import METRICS, MetricRow, MetricValues, find_row
from vprsnn_export.stats import MeanStd

from .measurements import (
    VERDICTS,
    Comparison,
    ConformanceResult,
    DecisionLevel,
    LevelHistogram,
    ModuleRow,
    PairedCheck,
    PrCurve,
    SpikeLevel,
    ToleranceCheck,
    WeightHistogram,
    worst_verdict,
)

SCHEMA = "vprsnn-verify-report/1"


class ReportError(VprError):
    """A missing or malformed report.json."""


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
    # the checkpoint file, when the caller names it
    checkpoint: str | None = field(default=None, metadata=json_options(omit="none"))
    # queries of the step-level checks (None: all; runtime.verify.run.RASTER_BUDGET)
    recorded_queries: int | None = field(default=None, metadata=json_options(omit="none"))

    __json_extra__ = ("passed", "verdict", "degenerate")
    __json_order__ = (
        *("label", "seed", "config", "checkpoint_sha256", "checkpoint_data", "query", "n_queries"),
        *("query_place_ids", "reference_place_ids", "export_dir", "float", "bits", "passed", "verdict", "degenerate"),
    )

    @property
    def passed(self) -> bool:
        return all(r.passed for r in self.bits)

    @property
    def degenerate(self) -> str | None:
        """Why the float network does not recognise places, or None when it does: R@100P = 0 at every k of W+Prob
        (no decision is right at 100 % precision), or W+Prob accuracy at k=1 within two binomial standard errors of
        chance, c + 2 sqrt(c (1 - c) / Q) with c = 1 / places. A width that "holds" against such a network keeps
        nothing worth keeping."""
        rows = [row for row in self.float.metrics if row.strategy == "wprob"]
        if not rows:
            return None
        if all(row.r_at_100p == 0 for row in rows):
            return "R@100P = 0 at every k (no decision is right at 100 % precision)"
        places = len(self.reference_place_ids)
        first = next((row for row in rows if row.k == 1), None)
        if places and first is not None:
            chance = 1.0 / places
            margin = chance + 2 * (chance * (1 - chance) / max(self.n_queries, 1)) ** 0.5
            if first.accuracy <= margin:
                return f"W+Prob accuracy at k=1 is {100 * first.accuracy:.1f} %, within chance ({100 * chance:.2f} %)"
        return None

    @property
    def verdict(self) -> str:
        return worst_verdict(r.verdict for r in self.bits)

    @property
    def ks(self) -> list[int]:
        return sorted({row.k for row in self.float.metrics})


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
    def degenerate(self) -> str | None:
        """The networks whose float network does not recognise places, with why ("net: reason; ..."), or None."""
        named = [f"{run.label or i + 1}: {run.degenerate}" for i, run in enumerate(self.runs) if run.degenerate]
        return "; ".join(named) or None

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
        if problem := _problem(data, report):
            raise ReportError(problem, source)
        return report


def _problem(data: Mapping[str, Any], report: VerifyReport) -> str | None:
    """What no verify run writes, the first found: a run without bit widths, a NaN or infinite number, a value
    outside its range, a stored verdict that its checks contradict; None when there is nothing."""
    if any(not run.bits for run in report.runs):
        return "a run of the report holds no bit widths"
    if problem := _non_finite(data) or _out_of_range(report):
        return problem
    if data.get("passed") is not report.passed:
        return f"the stored verdict passed={data.get('passed')!r} does not match the report's checks"
    return None


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
        for name, rows in (("float", run.float.metrics), *((f"{r.bits} bits", r.metrics) for r in run.bits)):
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
    "VERDICTS",
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
