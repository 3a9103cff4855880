"""The measurements a verification records, one frozen dataclass each (the parts of report.json and export.json).

Per readout :class:`ToleranceCheck` and :class:`PairedCheck`; per bit width :class:`SpikeLevel`,
:class:`DecisionLevel`, curves, histograms and :class:`ModuleRow`; per model :class:`Comparison` and
:class:`ConformanceResult`. Each maps to JSON by :mod:`vprsnn_export.io.serial`.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.io.serial import JsonDataclass, json_options


@dataclass(frozen=True)
class ToleranceCheck(JsonDataclass):
    """One enabled tolerance: the value, the limit set and the limit applied, and the verdict."""

    check: str
    what: str
    value: float
    limit: float
    applied_limit: float = field(metadata=json_options(missing_from=lambda data: data["limit"]))  # older: the limit set
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


@dataclass(frozen=True)
class PrCurve(JsonDataclass):
    """The exact precision-recall operating points of one score matrix."""

    precision: tuple[float, ...]
    recall: tuple[float, ...]

    def __post_init__(self) -> None:
        values = np.asarray([*self.precision, *self.recall], dtype=np.float64)
        if len(self.precision) != len(self.recall) or not np.all((values >= 0) & (values <= 1)):
            raise InvalidValueError(
                f"a PR curve needs as many precision as recall values, each in [0, 1] (got {len(self.precision)} "
                f"and {len(self.recall)})"
            )


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


@dataclass(frozen=True)
class ModuleRow(JsonDataclass):
    """One module of an ensemble at one bit width, against the float ensemble on the same queries.

    Accuracies are the **whole-route** W+Prob decisions scored on the queries whose true place lies in this module's
    region, at k=1 and the largest k; ``winner_agreement``: the share of (query, step) pairs on which this module's
    WTA picks the float module's winner (or both stay silent).
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
        return self.accuracy_k - self.float_accuracy_k


def _family(data: Mapping[str, Any]) -> str:
    """A comparison's family, from the keys its JSON object holds."""
    return "distribution" if "max_abs_difference" in data else "array" if "n_elements" in data else "config"


def _stated_tolerance(data: Mapping[str, Any]) -> float | None:
    """An older file's tolerance row: its kind ``decision agreement >= 95.0%`` (exact rows: None)."""
    match = re.fullmatch(r"decision agreement >= ([0-9.]+)%", str(data.get("kind", "")))
    return None if match is None else float(match.group(1)) / 100


#: How a float consumer's row says how many raster entries differ ("...; 2940 of 40960 raster entries differ ...").
_RASTER_DIFFERENCES = re.compile(r"\b(\d+) of \d+ raster entries differ")


@dataclass(frozen=True)
class Comparison(JsonDataclass):
    """One comparison of two implementations' outputs (``kind`` says how: "exact" or a bound).

    ``family``: "array" (element by element), "distribution" (W+Prob: identical decisions, |diff| bounded) or
    "config"; ``equal``: the outputs are identical. A **tolerance row** (``tolerance`` set: a float consumer's
    decisions must agree on at least that share of ``n_elements``) passes within it; it is never counted as exact.
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
    family: str = field(default="array", metadata=json_options(write=False, missing_from=_family))
    tolerance: float | None = field(default=None, metadata=json_options(omit="none", missing_from=_stated_tolerance))

    # the keys each family writes, in this order
    __json_extra__ = ("passed",)
    __json_order__: ClassVar[tuple[str, ...]] = (
        *("check", "a", "b", "kind", "equal", "tolerance", "passed", "n_elements", "max_abs_difference"),
        *("n_differences", "first_difference", "detail"),
    )

    def __post_init__(self) -> None:
        """A tolerance row claims ``equal`` only for what it measured identical (report_v1 wrote ``equal: true``
        for "passed", a consumer that refused the file included): it compared decisions (``n_elements`` > 0), none
        differ (``n_differences`` = 0) and its detail names no differing raster entry."""
        counted = _RASTER_DIFFERENCES.search(self.detail)
        identical = bool(self.n_elements) and self.n_differences == 0 and (counted is None or counted.group(1) == "0")
        if self.tolerance is not None and self.equal and not identical:
            object.__setattr__(self, "equal", False)

    @property
    def passed(self) -> bool:
        """Exact rows: identical. Tolerance rows: the agreeing share 1 - n_differences / n_elements reaches the
        tolerance (a row that compared nothing, a consumer refusing the file, is not gated)."""
        if self.tolerance is None:
            return self.equal
        return self.difference is None or 1.0 - self.difference >= self.tolerance - 1e-12

    @property
    def difference(self) -> float | None:
        """A tolerance row's measured difference: the share of decisions that differ (None when none compared)."""
        return None if not self.n_elements else (self.n_differences or 0) / self.n_elements


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
    def tolerance_rows(self) -> tuple[Comparison, ...]:
        """The rows judged within a stated tolerance (the float NIR consumers' decisions)."""
        return tuple(c for c in self.comparisons if c.tolerance is not None)

    @property
    def n_exact(self) -> int:
        """The exact rows (any difference fails): every row but the tolerance rows."""
        return self.n_checks - self.n_tolerance

    @property
    def n_identical(self) -> int:
        return sum(c.equal for c in self.comparisons if c.tolerance is None)

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
        return dataclasses.replace(self, files={**self.files, name: tuple(paths)})
