"""Runs summarised as mean ± std per bit width, and the report (:func:`build_report`) with its versions."""

from __future__ import annotations

import datetime
import platform
from collections.abc import Mapping, Sequence
from importlib import metadata
from typing import Any

import torch

from vprsnn_export.readout.metrics import METRICS, MetricRow
from vprsnn_export.readout.strategies import STRATEGIES
from vprsnn_export.stats import mean_std
from vprsnn_export.version import __version__

from ..measurements import VERDICTS
from ..results import BitsResult, BitsSummary, RunSummary, SummaryRow, VerifiedRun, VerifyReport


def summary_rows(rows_per_run: Sequence[Sequence[MetricRow]], with_delta: bool) -> tuple[SummaryRow, ...]:
    """Mean ± std of each (strategy, k) row over runs, in the order the rows first appear."""
    groups: dict[tuple[str, int], list[MetricRow]] = {}
    for row in (row for rows in rows_per_run for row in rows):
        groups.setdefault((row.strategy, row.k), []).append(row)
    return tuple(
        SummaryRow(
            strategy,
            k,
            {m: mean_std(r.values.get(m) for r in rows) for m in METRICS},
            {m: mean_std(r.delta.get(m) if r.delta else None for r in rows) for m in METRICS} if with_delta else None,
        )
        for (strategy, k), rows in groups.items()
    )


def summarise_bits(bits: int, results: Sequence[BitsResult]) -> BitsSummary:
    """Mean ± std over networks of every measurement at one bit width."""
    ks = sorted({k for r in results for k in r.decision_level.aggregated_agreement})
    return BitsSummary(
        bits=bits,
        n_runs=len(results),
        n_passed=sum(r.passed for r in results),
        cross_implementation_passed=sum(r.cross_implementation.passed for r in results),
        metrics=summary_rows([r.metrics for r in results], with_delta=True),
        winner_agreement=mean_std(r.spike_level.winner_agreement for r in results),
        count_correlation=mean_std(r.spike_level.count_correlation_mean for r in results),
        spike_ratio=mean_std(r.spike_level.spike_ratio for r in results),
        saturations=mean_std(r.spike_level.saturations for r in results),
        top1_agreement={s: mean_std(r.decision_level.top1_agreement[s] for r in results) for s in STRATEGIES},
        wprob_tv_mean=mean_std(r.decision_level.wprob_tv_mean for r in results),
        aggregated_agreement={k: mean_std(r.decision_level.aggregated_agreement.get(k) for r in results) for k in ks},
        verdicts={v: sum(r.verdict == v for r in results) for v in VERDICTS},
    )


def summarise_runs(runs: Sequence[VerifiedRun]) -> RunSummary:
    """Mean ± std over runs (independently trained networks) of every metric and check, per bit width."""
    per_bits: dict[int, list[BitsResult]] = {}
    for result in (result for run in runs for result in run.bits):
        per_bits.setdefault(result.bits, []).append(result)
    return RunSummary(
        n_runs=len(runs),
        float=summary_rows([run.float.metrics for run in runs], with_delta=False),
        bits=tuple(summarise_bits(bits, per_bits[bits]) for bits in sorted(per_bits, reverse=True)),
        passed=all(run.passed for run in runs),
    )


def versions() -> dict[str, str]:
    """Package and library versions recorded in every report."""
    out = {
        "vprsnn-export": __version__,
        "python": platform.python_version(),
        "platform": platform.platform(),
        "machine": f"{platform.machine()}, {torch.get_num_threads()} torch threads",
    }
    for name in ("torch", "numpy", "onnx", "onnxruntime", "nir", "h5py", "matplotlib"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "absent"
    return out


def build_report(
    runs: Sequence[VerifiedRun],
    settings: Mapping[str, Any],
    *,
    command: Sequence[str] | None = None,
    seconds: float | None = None,
) -> VerifyReport:
    """The whole report: settings, versions, every run, the summary and the verdict."""
    return VerifyReport(
        created=datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        command=None if command is None else tuple(command),
        seconds=None if seconds is None else round(float(seconds), 1),
        versions=versions(),
        settings=dict(settings),
        runs=tuple(runs),
        summary=summarise_runs(runs),
    )
