"""report.json -> report.md and a self-contained report.html; several reports -> one, as mean ± std.

The report is built from the JSON alone (nothing is re-run), so ``vprsnn-export report``
can rebuild it anywhere. The document is a list of blocks (headings, paragraphs,
tables, figures) rendered twice: Markdown, whose figures are PNG files in ``plots/``
beside it, and HTML, whose figures are base64 PNGs inline (matplotlib Agg, no external
asset of any kind).
"""

from __future__ import annotations

import base64
import dataclasses
import html
import io
import json
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.fileio import atomic_write_bytes, atomic_write_text, parse_json
from vprsnn_export.readout.strategies import SEQUENCE_STRATEGY, STRATEGIES
from vprsnn_export.stats import MeanStd

from .results import (
    METRICS,
    ReportError,
    RunSummary,
    VerifiedRun,
    VerifyReport,
)
from .verify import TOLERANCE_MEANING, build_report, summarise_runs

REPORT_JSON = "report.json"
REPORT_MD = "report.md"
REPORT_HTML = "report.html"
PLOTS_DIR = "plots"
METRIC_TITLES = {"accuracy": "Accuracy", "p_at_100r": "P@100R", "r_at_100p": "R@100P", "auc_pr": "AUC-PR"}


def pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend, imported on first use (it costs ~0.8 s at start-up)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


# ---------------------------------------------------------------------------- reading and combining


def report_path(path: str | Path) -> Path:
    """A run folder (holding report.json) or the report.json itself."""
    path = Path(path)
    return path / REPORT_JSON if path.is_dir() else path


def load_report(path: str | Path) -> VerifyReport:
    """The report of a report.json (or of the folder holding one); ReportError when it is not one."""
    file = report_path(path)
    if not file.is_file():
        raise ReportError(f"no {REPORT_JSON} here (give a folder written by verify, or its {REPORT_JSON})", file)
    try:
        data = parse_json(file.read_bytes(), REPORT_JSON)
    except (UnicodeDecodeError, json.JSONDecodeError, InvalidValueError) as exc:
        raise ReportError(f"not valid JSON ({exc})", file) from None
    return VerifyReport.from_dict(data, str(file))


#: Settings that make two verification runs measure different things: pooling them into one
#: mean ± std needs the user's explicit consent (``allow_mixed``).
POOLING_KEYS = ("query", "data", "subset", "places", "bits", "readout", "per_neuron", "scale_method", "calibration")


def _as_json(value: Any) -> str:
    """A setting as JSON text, so a tuple and the list a JSON file gives back compare equal."""
    return json.dumps(value, sort_keys=True, default=str)


def combine_reports(
    reports: Sequence[VerifyReport], sources: Sequence[str] | None = None, *, allow_mixed: bool = False
) -> VerifyReport:
    """One report holding every run of ``reports``; the summary becomes mean ± std over all of them.

    Settings come from the first report; keys on which the others differ are listed under
    ``settings_differ`` (and shown in the report). Reports that differ in a :data:`POOLING_KEYS`
    setting (other data, bit widths, readout) are refused unless ``allow_mixed``.
    """
    if not reports:
        raise ReportError("no reports to combine")
    if len(reports) == 1:
        return dataclasses.replace(reports[0], summary=summarise_runs(reports[0].runs))
    runs = [run for report in reports for run in report.runs]
    settings = dict(reports[0].settings)
    differ = sorted(
        {
            key
            for report in reports[1:]
            for key in set(settings) | set(report.settings)
            if _as_json(report.settings.get(key)) != _as_json(settings.get(key))
        }
    )
    incompatible = [key for key in differ if key in POOLING_KEYS]
    if incompatible and not allow_mixed:
        raise ReportError(
            f"the reports differ in {', '.join(incompatible)}: pooling them into one mean ± std would mix different "
            "measurements (--allow-mixed to pool them anyway)"
        )
    return dataclasses.replace(
        build_report(runs, settings, command=None),
        seconds=sum(float(report.seconds or 0) for report in reports),
        combined_from=tuple(sources or ()),
        commands=tuple(report.command for report in reports),
        settings_differ=tuple(differ),
    )


# ---------------------------------------------------------------------------- blocks


@dataclass
class Block:
    kind: str  # h1, h2, h3, p, table, figure, pre
    text: str = ""
    headers: Sequence[str] = ()
    rows: Sequence[Sequence[str]] = ()
    image: bytes = b""
    name: str = ""
    status: Sequence[str | None] = ()  # per table row: "pass", "fail" or None (HTML colours)
    title: str = ""  # figures: the heading above the image (``text`` is the caption); pre: a collapsed summary


def signed_pct(value: float | None, digits: int = 1) -> str:
    return "-" if value is None else f"{round(100 * value, digits) + 0.0:+.{digits}f}"


def ms(summary: MeanStd | None, *, percent: bool = True, signed: bool = False, digits: int = 1) -> str:
    """A mean ± std cell (just the mean for a single run)."""
    if summary is None or summary.mean is None:
        return "-"
    scale = 100.0 if percent else 1.0
    value = round(scale * summary.mean, digits) + 0.0  # no "-0.0"
    mean = f"{value:{'+' if signed else ''}.{digits}f}"
    return mean if summary.n <= 1 else f"{mean} ± {scale * (summary.std or 0.0):.{digits}f}"


def data_note(settings: Mapping[str, Any]) -> str:
    """ " from DATA (selection)" when the settings name the data."""
    if not settings.get("data"):
        return ""
    selection = settings.get("subset") or (f"places {settings['places']}" if settings.get("places") else "all places")
    return f" from {settings['data']} ({selection})"


def strategy_title(strategy: str) -> str:
    """A strategy's title in the report (its registry entry's; a name not registered stays as it is)."""
    return STRATEGIES.get(strategy).title if strategy in STRATEGIES else strategy


def row_label(strategy: str, k: int) -> str:
    return f"{strategy_title(strategy)} k={k}"


def verdict(passed: bool) -> str:
    return "PASS" if passed else "FAIL"


def network_label(run: VerifiedRun, index: int) -> str:
    return run.label or str(index + 1)


def points(check: str, value: float) -> str:
    """A tolerance value in the unit the terminal also uses: percentage points, or a count (saturations)."""
    return str(int(value)) if check == "saturations" else f"{100 * value:.1f} pts"


def failure_lines(report: VerifyReport) -> list[str]:
    """Each failed check, named with its network and bit width: what the verdict line's FAIL means."""
    lines = []
    for index, run in enumerate(report.runs):
        network = run.label or f"network {index + 1}"
        for result in run.bits:
            if not result.cross_implementation.passed:
                lines.append(
                    f"{network}, {result.bits} bits: {result.cross_implementation.n_failed} cross-implementation differences"
                )
            for check in result.tolerance_checks:
                if not check.passed:
                    value, limit = points(check.check, check.value), points(check.check, check.applied_limit)
                    lines.append(f"{network}, {result.bits} bits: {check.what} = {value} (limit {limit})")
    return lines


def blocks_of(report: VerifyReport) -> list[Block]:
    """The whole document, format-neutral."""
    summary = report.summary
    runs = report.runs
    n_runs = len(runs)
    first = runs[0]
    ks = first.ks
    top_k = max(ks)
    networks = f"mean ± std over {n_runs} independently trained networks" if n_runs > 1 else "one network"
    blocks: list[Block] = [Block("h1", "vprsnn-export verification report")]
    blocks.append(
        Block(
            "p",
            (
                f"**Verdict: {verdict(report.passed)}** — {report.n_passed} of {n_runs} network(s) pass every "
                f"check at every bit width. Query traversal **{first.query}**, {first.n_queries} queries"
                f"{data_note(report.settings)}; {networks}. Generated {report.created}"
                + (f" in {report.seconds:.0f} s" if report.seconds else "")
                + "."
            ),
        )
    )
    failures = failure_lines(report)
    if failures:
        blocks.append(Block("p", "**Failed:** " + "; ".join(failures) + "."))
    if report.settings_differ:
        blocks.append(
            Block(
                "p",
                "Combined reports whose settings differ in: "
                + ", ".join(report.settings_differ)
                + " (settings shown are the first report's).",
            )
        )
    blocks += verdict_blocks(report, top_k)
    blocks += metric_blocks(summary, ks)
    blocks.append(
        Block(
            "figure",
            title="Metrics vs weight bit width",
            image=plot_metrics(summary, ks),
            name="metrics_vs_bits.png",
            text="Each metric vs bit width; the float network's value is the dashed line of the same colour"
            + (" (mean ± std over networks)." if n_runs > 1 else "."),
        )
    )
    blocks.append(
        Block(
            "figure",
            title="Precision-recall curves",
            image=plot_pr(first),
            name="pr_curves.png",
            text=f"W+Prob at k=1 and k={top_k}, float (black) vs each bit width"
            + (f"; network {first.label or 1} of {n_runs}." if n_runs > 1 else "."),
        )
    )
    blocks += spike_blocks(summary, runs)
    blocks.append(
        Block(
            "figure",
            title="Spike-count agreement",
            image=plot_spikes(report),
            name="spike_agreement.png",
            text="Left: fraction of time steps with the float winner, top-1 agreement and mean per-query "
            "spike-count correlation vs bit width. Right: distribution of the per-query correlation "
            "of the float and quantised spike-count vectors (all networks pooled).",
        )
    )
    blocks += decision_blocks(summary, ks)
    blocks += module_blocks(first, n_runs)
    blocks += cross_blocks(report)
    blocks += quantisation_blocks(first)
    blocks.append(
        Block(
            "figure",
            title="Weight histograms",
            image=plot_weights(first),
            name="weight_histograms.png",
            text="Float weights divided by their scale range "
            f"({first.float.weights.normalised_by}): the share of weights on each quantised level "
            "q / L, L = 2^b - 1 (bars), and the share of float weights within 1 / L around each point (line).",
        )
    )
    blocks += tolerance_blocks(report)
    blocks += provenance_blocks(report)
    return blocks


def verdict_blocks(report: VerifyReport, top_k: int) -> list[Block]:
    tolerances = report.settings.get("tolerances", {})
    rows, status = [], []
    for bits in report.summary.bits:
        worst_acc = min(
            (
                row.delta["accuracy"].mean
                for s in STRATEGIES
                if (row := bits.row(s, 1)) is not None
                and row.delta is not None
                and row.delta["accuracy"].mean is not None
            ),
            default=None,
        )
        top = bits.row("wprob", top_k)
        ok = bits.n_passed == bits.n_runs
        rows.append(
            [
                f"{bits.bits}",
                f"{verdict(ok)} ({bits.n_passed}/{bits.n_runs})",
                f"{bits.cross_implementation_passed}/{bits.n_runs} exact",
                signed_pct(worst_acc),
                ms(top.delta["r_at_100p"], signed=True) if top and top.delta else "-",
                ms(top.values["r_at_100p"]) if top else "-",
                ms(bits.winner_agreement),
                ms(bits.saturations, percent=False, digits=0),
            ]
        )
        status.append("pass" if ok else "fail")
    limits = ", ".join(f"{key} {value:g}" for key, value in tolerances.items() if value is not None)
    return [
        Block("h2", "Pass / fail per bit width"),
        Block(
            "table",
            headers=[
                "bits",
                "verdict (networks)",
                "cross-implementation",
                "worst accuracy Δ k=1 (pts)",
                f"R@100P Δ W+Prob k={top_k} (pts)",
                f"R@100P W+Prob k={top_k} %",
                "same winner %",
                "saturations",
            ],
            rows=rows,
            status=status,
        ),
        Block(
            "p",
            f"Tolerances: {limits or 'none'} (drops from float, in fractions; see docs/verify.md). "
            "Δ = quantised - float, in percentage points; negative is worse.",
        ),
    ]


def metric_blocks(summary: RunSummary, ks: Sequence[int]) -> list[Block]:
    blocks = [Block("h2", "Metric level")]
    float_rows = {(r.strategy, r.k): r for r in summary.float}
    labels = [(s, 1) for s in STRATEGIES] + [("wprob", k) for k in ks if k > 1]
    for metric in METRICS:
        headers = ["readout", "float %"] + [f"{b.bits}-bit % (Δ)" for b in summary.bits]
        rows = []
        for key in labels:
            if key not in float_rows:
                continue
            cells = [row_label(*key), ms(float_rows[key].values[metric])]
            for bits in summary.bits:
                row = bits.row(*key)
                delta = "-" if row is None or row.delta is None else ms(row.delta[metric], signed=True)
                cells.append("-" if row is None else f"{ms(row.values[metric])} ({delta})")
            rows.append(cells)
        blocks += [Block("h3", METRIC_TITLES[metric]), Block("table", headers=headers, rows=rows)]
    return blocks


def spike_blocks(summary: RunSummary, runs: Sequence[VerifiedRun] = ()) -> list[Block]:
    rows = [
        [
            f"{b.bits}",
            ms(b.winner_agreement, digits=2),
            ms(b.count_correlation, percent=False, digits=3),
            ms(b.spike_ratio, percent=False, digits=3),
            ms(b.saturations, percent=False, digits=0),
        ]
        for b in summary.bits
    ]
    return [
        Block("h2", "Spike level"),
        Block(
            "p",
            "Same float and quantised input spikes; per time step, do both networks emit the same spike (the "
            "WTA winner, or both silent)? Per query, how well do the two spike-count vectors correlate? "
            "Spike ratio = quantised / float total spikes. Saturations: voltage clips on the queries."
            + recorded_note(runs),
        ),
        Block("table", headers=["bits", "same winner %", "count correlation", "spike ratio", "saturations"], rows=rows),
    ]


def recorded_note(runs: Sequence[VerifiedRun]) -> str:
    """The sentence saying that step-level checks ran on the first queries only (a large network)."""
    partial = [run for run in runs if run.recorded_queries is not None and run.recorded_queries < run.n_queries]
    if not partial:
        return ""
    run = partial[0]
    return (
        f" Same winner, the per-module agreement and the exported files' rasters are compared on the first "
        f"{run.recorded_queries} of {run.n_queries} queries (a recorded raster of every query would not fit in "
        "memory); counts, correlations, saturations and every metric use all queries."
    )


def decision_blocks(summary: RunSummary, ks: Sequence[int]) -> list[Block]:
    agg_ks = [k for k in ks if k > 1]
    headers = (
        ["bits"]
        + [f"top-1 {strategy_title(s)} %" for s in STRATEGIES]
        + ["W+Prob TV distance"]
        + [f"agreement k={k} %" for k in agg_ks]
    )
    rows = []
    for b in summary.bits:
        rows.append(
            [f"{b.bits}"]
            + [ms(b.top1_agreement.get(s)) for s in STRATEGIES]
            + [ms(b.wprob_tv_mean, percent=False, digits=3)]
            + [ms(b.aggregated_agreement.get(k)) for k in agg_ks]
        )
    return [
        Block("h2", "Decision level"),
        Block(
            "p",
            "Top-1 agreement: share of queries where the quantised network picks the same place as the float "
            "one (or both reject). TV distance: mean total variation between the float and quantised W+Prob "
            "distributions (0 = identical, 1 = disjoint). Aggregated: the same agreement after k-frame "
            "sequence aggregation.",
        ),
        Block("table", headers=headers, rows=rows),
    ]


def cross_blocks(report: VerifyReport) -> list[Block]:
    rows, status, failures = [], [], []
    for index, run in enumerate(report.runs):
        for result in run.bits:
            cross = result.cross_implementation
            kinds = sorted({c.check.split(":")[0] for c in cross.comparisons})
            skipped = "; skipped: " + ", ".join(f"{k} ({v})" for k, v in cross.skipped.items()) if cross.skipped else ""
            rows.append(
                [
                    network_label(run, index),
                    f"{result.bits}",
                    f"{cross.n_checks - cross.n_failed}/{cross.n_checks}",
                    verdict(cross.passed),
                    str(cross.reference_queries),
                    "; ".join(kinds) + skipped,
                ]
            )
            status.append("pass" if cross.passed else "fail")
            failures += [[network_label(run, index), f"{result.bits}", c.check, c.detail] for c in cross.failures]
    blocks = [
        Block("h2", "Cross-implementation (exact)"),
        Block(
            "p",
            "Integer simulator vs ONNX on onnxruntime vs the NIR and Loihi-style files read back and re-run vs "
            "the slow reference stepper (on the first queries only: it is a per-neuron Python loop). Rasters, "
            "counts, candidate counts, final voltages, saturations and every integer array are compared bit "
            "for bit; the ONNX W+Prob head must give identical decisions (float64, |diff| <= 1e-12). Any "
            "difference fails.",
        ),
        Block(
            "table",
            headers=["network", "bits", "identical", "verdict", "reference-stepper queries", "implementations"],
            rows=rows,
            status=status,
        ),
    ]
    if failures:
        blocks += [
            Block("h3", "Differences found"),
            Block(
                "table", headers=["network", "bits", "check", "detail"], rows=failures, status=["fail"] * len(failures)
            ),
        ]
    return blocks


def module_blocks(run: VerifiedRun, n_runs: int) -> list[Block]:
    """An ensemble's per-module table (whole-route accuracy on each region's queries) and its plot."""
    if not any(result.modules for result in run.bits):
        return []
    first = next(result.modules for result in run.bits if result.modules)
    k = first[0].k
    headers = ["module", "places", "queries", "float k=1 %", f"float k={k} %"]
    for result in run.bits:
        headers += [f"{result.bits}-bit k={k} % (Δ)", f"{result.bits}-bit same winner %"]
    rows = []
    for index, module in enumerate(first):
        cells = [
            str(module.module),
            f"{module.first_place}-{module.last_place}",
            str(module.n_queries),
            f"{100 * module.float_accuracy:.1f}",
            f"{100 * module.float_accuracy_k:.1f}",
        ]
        for result in run.bits:
            row = result.modules[index]
            cells += [f"{100 * row.accuracy_k:.1f} ({signed_pct(row.delta_k)})", f"{100 * row.winner_agreement:.1f}"]
        rows.append(cells)
    worst = []
    for result in run.bits:
        low = min(result.modules, key=lambda m: (m.delta_k, m.winner_agreement))
        worst.append(
            f"{result.bits}-bit: module {low.module} (places {low.first_place}-{low.last_place}, "
            f"{signed_pct(low.delta_k)} pts at k={k}, {100 * low.winner_agreement:.1f} % same winner)"
        )
    which = f" (network {run.label or 1} of {n_runs})" if n_runs > 1 else ""
    return [
        Block("h2", f"Modules of the ensemble{which}"),
        Block(
            "p",
            f"{len(first)} modules. "
            "Accuracy is the whole-route W+Prob decision (every module's neurons, every place) scored on the "
            "queries whose true place lies in the module's region; same winner: the share of time steps on "
            "which the module's WTA picks the float module's winner. The module that degrades most: "
            + "; ".join(worst)
            + ".",
        ),
        Block("table", headers=headers, rows=rows),
        Block(
            "figure",
            title="Accuracy per module",
            image=plot_modules(run),
            name="modules.png",
            text=f"Whole-route W+Prob accuracy at k={k} on each module's region, float (black) vs each bit width.",
        ),
    ]


def quantisation_blocks(run: VerifiedRun) -> list[Block]:
    rows = []
    for result in run.bits:
        q = result.quantisation
        rows.append(
            [
                f"{result.bits}",
                ("per-neuron" if q.per_neuron else "per-tensor") + f", {q.scale_method}",
                f"{q.weight_relative_rmse or 0:.4f}",
                str(q.weights_clipped),
                f"{100 * (q.threshold_max_relative_error or 0):.3f}",
                f"{100 * result.weight_levels.zero_fraction:.1f}",
                str(q.max_current),
                str(q.calibration),
                str(q.calibration_saturations),
            ]
        )
    return [
        Block("h2", "Quantisation"),
        Block(
            "table",
            headers=[
                "bits",
                "scales",
                "weight rel. RMSE",
                "clipped weights",
                "max threshold error %",
                "weights at 0 %",
                "max current",
                "calibration",
                "calibration saturations",
            ],
            rows=rows,
        ),
    ]


def tolerance_blocks(report: VerifyReport) -> list[Block]:
    rows, status = [], []
    for index, run in enumerate(report.runs):
        for result in run.bits:
            for check in result.tolerance_checks:
                percent = check.check not in ("saturations",)
                value = f"{100 * check.value:.2f}" if percent else str(check.value)
                applied = check.applied_limit
                limit = f"{100 * applied:.2f}" if percent else f"{applied:g}"
                if applied != check.limit:
                    limit += f" (1 query; set {100 * check.limit:.2f})"
                rows.append(
                    [network_label(run, index), f"{result.bits}", check.what, value, limit, verdict(check.passed)]
                )
                status.append("pass" if check.passed else "fail")
    meaning = "; ".join(f"{k}: {TOLERANCE_MEANING[k]}" for k in TOLERANCE_MEANING)
    return [
        Block("h2", "Tolerance checks"),
        Block(
            "p",
            "Values and limits in percentage points (drops) or percent (agreements). A metric moves in steps of "
            "one query (100/Q points), so a drop limit below query_slack queries is raised to it. "
            f"Keys — {meaning}.",
        ),
        Block("table", headers=["network", "bits", "check", "value", "limit", "verdict"], rows=rows, status=status),
    ]


def provenance_blocks(report: VerifyReport) -> list[Block]:
    rows = []
    for index, run in enumerate(report.runs):
        rows.append(
            [
                network_label(run, index),
                str(run.seed),
                run.checkpoint_sha256[:16],
                str(run.checkpoint_data.get("source")),
                f"{run.n_queries}",
                str(run.export_dir or "-"),
            ]
        )
    if report.command:
        text = " ".join(report.command)
    else:
        text = "\n".join(" ".join(c) for c in report.commands or () if c) or "-"
    return [
        Block("h2", "Networks"),
        Block("table", headers=["network", "seed", "checkpoint sha256", "data", "queries", "exports"], rows=rows),
        Block("h2", "Provenance"),
        Block("pre", "command: " + text),
        Block("pre", json.dumps(dict(report.settings), indent=2, sort_keys=True), title="settings"),
        Block("pre", json.dumps(dict(report.runs[0].config), indent=2, sort_keys=True), title="config (first network)"),
        Block("pre", json.dumps(dict(report.versions), indent=2, sort_keys=True), title="versions"),
    ]


# ---------------------------------------------------------------------------- plots


def png(fig: Any) -> bytes:
    plt = pyplot()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    return buffer.getvalue()


def _series(summary: RunSummary, key: tuple[str, int], metric: str) -> tuple[list[int], list[float], list[float]]:
    xs, means, stds = [], [], []
    for bits in summary.bits:
        row = bits.row(*key)
        if row is not None and row.values[metric].mean is not None:
            xs.append(bits.bits)
            means.append(100 * (row.values[metric].mean or 0.0))
            stds.append(100 * (row.values[metric].std or 0.0))
    return xs, means, stds


def plot_metrics(summary: RunSummary, ks: Sequence[int]) -> bytes:
    plt = pyplot()
    keys = [(s, 1) for s in STRATEGIES] + [("wprob", k) for k in ks if k > 1]
    float_rows = {(r.strategy, r.k): r for r in summary.float}
    fig, axes = plt.subplots(2, 2, figsize=(10, 7))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    markers = "osD^vP*X"
    bits = sorted({b.bits for b in summary.bits})
    for ax, metric in zip(axes.ravel(), METRICS, strict=True):
        for index, key in enumerate(keys):
            colour = colours[index % len(colours)]
            xs, means, stds = _series(summary, key, metric)
            if xs:
                ax.errorbar(
                    xs,
                    means,
                    yerr=stds,
                    marker=markers[index % len(markers)],
                    capsize=3,
                    color=colour,
                    label=row_label(*key),
                    markersize=8 - index,
                    alpha=0.9,
                )
            mean = float_rows[key].values[metric].mean if key in float_rows else None
            if mean is not None:
                ax.axhline(100 * mean, color=colour, linestyle="--", linewidth=1)
        ax.set_title(METRIC_TITLES[metric])
        ax.set_ylabel("%")
        ax.grid(alpha=0.3)
        ax.set_xticks(bits)
        ax.set_xlim(max(bits) + 0.5, min(bits) - 0.5)  # fewer bits to the right
    for ax in axes[1]:
        ax.set_xlabel("weight bits (dashed: float)")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=9, frameon=False)
    return png(fig)


def plot_pr(run: VerifiedRun) -> bytes:
    plt = pyplot()
    names = list(run.float.pr_curves)
    fig, axes = plt.subplots(1, len(names), figsize=(5 * len(names), 4.2), squeeze=False)
    cmap = plt.get_cmap("viridis")
    n = max(len(run.bits) - 1, 1)
    for ax, name in zip(axes[0], names, strict=True):
        curve = run.float.pr_curves[name]
        ax.step(curve.recall, curve.precision, where="post", color="black", linewidth=2, label="float")
        for index, result in enumerate(run.bits):
            if name in result.pr_curves:
                c = result.pr_curves[name]
                ax.step(c.recall, c.precision, where="post", color=cmap(index / n), label=f"{result.bits}-bit")
        ax.set_xlim(0, 1.02)
        ax.set_ylim(0, 1.05)
        ax.set_xlabel("recall")
        ax.set_ylabel("precision")
        ax.set_title(name.replace(SEQUENCE_STRATEGY, strategy_title(SEQUENCE_STRATEGY)))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower left")
    return png(fig)


def plot_modules(run: VerifiedRun) -> bytes:
    plt = pyplot()
    results = [result for result in run.bits if result.modules]
    modules = results[0].modules
    x = np.arange(len(modules))
    fig, axes = plt.subplots(2, 1, figsize=(max(6.0, 0.35 * len(modules) + 2), 5.2), sharex=True)
    cmap = plt.get_cmap("viridis")
    n = max(len(results) - 1, 1)
    for index, result in enumerate(results):
        color = cmap(index / n)
        axes[0].plot(x, [100 * m.accuracy_k for m in result.modules], ".-", color=color, label=f"{result.bits}-bit")
        axes[1].plot(x, [100 * m.winner_agreement for m in result.modules], ".-", color=color)
    # float last, open circles and dashed: a bit width equal to it stays visible inside them
    float_accuracy = [100 * m.float_accuracy_k for m in modules]
    axes[0].plot(x, float_accuracy, "o--", color="black", markerfacecolor="none", markersize=8, label="float")
    axes[0].set_ylabel(f"accuracy k={modules[0].k} %")
    axes[1].set_ylabel("same winner %")
    axes[1].set_xlabel("module (region of consecutive places)")
    axes[1].xaxis.set_major_locator(plt.MaxNLocator(integer=True))  # module numbers, never 0.5
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, ncol=len(results) + 1, loc="lower center", bbox_to_anchor=(0.5, 1.02))
    fig.tight_layout()
    return png(fig)


def window_share(edges: np.ndarray, counts: np.ndarray, x: np.ndarray, width: float) -> np.ndarray:
    """The share of a histogram's values within ``width`` around each ``x`` (uniform within a bin):
    ``share(x) = F(x + width/2) - F(x - width/2)``, F the cumulative share at the edges, interpolated.
    At x = q / L with width 1 / L it is the share of float weights that round to level q: a share, <= 1."""
    cdf = np.concatenate([[0.0], np.cumsum(counts)]) / max(float(np.sum(counts)), 1.0)
    return np.interp(x + width / 2, edges, cdf) - np.interp(x - width / 2, edges, cdf)


def plot_weights(run: VerifiedRun) -> bytes:
    """Per bit width: the share of weights on each level q / L (bars) over the float weights' share within
    a level's width 1 / L around each point (line, :func:`window_share`): the same units, both <= 1."""
    plt = pyplot()
    results = run.bits
    fig, axes = plt.subplots(1, len(results), figsize=(3.3 * len(results), 3.0), squeeze=False)
    hist = run.float.weights
    edges = np.asarray(hist.edges, dtype=np.float64)
    counts = np.asarray(hist.counts, dtype=np.float64)
    x = np.linspace(edges[0], edges[-1], 401)
    for ax, result in zip(axes[0], results, strict=True):
        levels = result.weight_levels
        top = levels.levels
        share = np.asarray(levels.counts, dtype=np.float64) / max(sum(levels.counts), 1)
        ax.bar(
            np.arange(top + 1) / top,
            share,
            width=0.85 / top,
            color="tab:orange",
            alpha=0.85,
            label=f"{result.bits}-bit levels",
        )
        ax.plot(x, window_share(edges, counts, x, 1 / top), color="tab:blue", linewidth=1.2, label="float")
        ax.set_title(f"{result.bits}-bit: {100 * levels.zero_fraction:.1f} % of weights at 0", fontsize=9)
        ax.set_xlabel("weight / scale range")
        ax.set_xlim(-0.08, 1.08)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=8)
    axes[0, 0].set_ylabel("share of weights")
    axes[0, 0].legend(fontsize=7)
    return png(fig)


def plot_spikes(report: VerifyReport) -> bytes:
    plt = pyplot()
    summary = report.summary
    bits = [b.bits for b in summary.bits]
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    series: tuple[tuple[str, list[MeanStd]], ...] = (
        ("same winner per step", [b.winner_agreement for b in summary.bits]),
        ("top-1 agreement W+Prob k=1", [b.top1_agreement["wprob"] for b in summary.bits]),
        ("mean count correlation", [b.count_correlation for b in summary.bits]),
    )
    for label, values in series:
        left.errorbar(
            bits,
            [100 * (v.mean or 0.0) for v in values],
            yerr=[100 * (v.std or 0.0) for v in values],
            marker="o",
            capsize=3,
            label=label,
        )
    left.set_xticks(sorted(bits))
    left.set_xlim(max(bits) + 0.5, min(bits) - 0.5)
    left.set_xlabel("weight bits")
    left.set_ylabel("%")
    left.set_ylim(0, 102)
    left.grid(alpha=0.3)
    left.legend(fontsize=8, loc="lower left")
    pooled = [
        [c for run in report.runs for r in run.bits if r.bits == b for c in r.spike_level.count_correlation]
        for b in bits
    ]
    right.boxplot(pooled)
    right.set_xticks(range(1, len(bits) + 1), [str(b) for b in bits])
    right.set_xlabel("weight bits")
    right.set_ylabel("per-query spike-count correlation")
    right.set_ylim(-0.05, 1.05)
    right.grid(alpha=0.3)
    return png(fig)


# ---------------------------------------------------------------------------- rendering


def render_markdown(blocks: Sequence[Block], plots_dir: str = PLOTS_DIR) -> str:
    lines: list[str] = []
    for block in blocks:
        if block.kind == "h1":
            lines += [f"# {block.text}", ""]
        elif block.kind == "h2":
            lines += [f"## {block.text}", ""]
        elif block.kind == "h3":
            lines += [f"### {block.text}", ""]
        elif block.kind == "p":
            lines += [block.text, ""]
        elif block.kind == "pre":
            lines += ([f"{block.title}:", ""] if block.title else []) + ["```", block.text, "```", ""]
        elif block.kind == "table":
            lines.append("| " + " | ".join(block.headers) + " |")
            lines.append("|" + "---|" * len(block.headers))
            lines += ["| " + " | ".join(str(c).replace("|", "\\|") for c in row) + " |" for row in block.rows]
            lines.append("")
        elif block.kind == "figure":
            lines += [
                f"### {block.title}",
                "",
                f"![{block.title}]({plots_dir}/{block.name})",
                "",
                f"*{block.text}*",
                "",
            ]
    return "\n".join(lines)


CSS = """
body { font-family: -apple-system, 'Segoe UI', Helvetica, Arial, sans-serif; margin: 2em auto; max-width: 1150px;
       color: #1d1d1f; line-height: 1.45; padding: 0 1em; }
h1 { border-bottom: 2px solid #444; padding-bottom: .2em; }
h2 { margin-top: 1.8em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: .6em 0 1em; font-size: 13px; }
th, td { border: 1px solid #ccc; padding: 3px 8px; text-align: right; }
th { background: #f0f0f3; }
td:first-child, th:first-child, td.t { text-align: left; }
details { margin: .4em 0; } summary { cursor: pointer; color: #333; }
tr.pass td { background: #eaf7ea; }
tr.fail td { background: #fbe3e3; }
figure { margin: 1em 0; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 13px; color: #555; }
pre { background: #f6f6f8; padding: .6em; overflow-x: auto; font-size: 12px; }
.verdict-pass { color: #17701f; } .verdict-fail { color: #b00020; }
"""


def _html_inline(text: str) -> str:
    escaped = html.escape(text)
    parts = escaped.split("**")
    out = []
    for index, part in enumerate(parts):
        out.append(f"<strong>{part}</strong>" if index % 2 else part)
    return (
        "".join(out)
        .replace("<strong>Verdict: PASS</strong>", '<strong class="verdict-pass">Verdict: PASS</strong>')
        .replace("<strong>Verdict: FAIL</strong>", '<strong class="verdict-fail">Verdict: FAIL</strong>')
    )


NUMERIC = re.compile(r"^[-+]?[\d./]+( ± [\d.]+)?( \([-+]?[\d.]+( ± [\d.]+)?\))?( exact)?$")


def _cell(value: object) -> str:
    """A table cell: numbers right-aligned, text left-aligned."""
    text = str(value)
    cls = "" if NUMERIC.match(text) or text in ("-", "PASS", "FAIL") else ' class="t"'
    return f"<td{cls}>{html.escape(text)}</td>"


def render_html(blocks: Sequence[Block], title: str = "vprsnn-export verification report") -> str:
    body: list[str] = []
    for block in blocks:
        if block.kind in ("h1", "h2", "h3"):
            body.append(f"<{block.kind}>{html.escape(block.text)}</{block.kind}>")
        elif block.kind == "p":
            body.append(f"<p>{_html_inline(block.text)}</p>")
        elif block.kind == "pre" and block.title:
            body.append(
                f"<details><summary>{html.escape(block.title)}</summary><pre>{html.escape(block.text)}</pre></details>"
            )
        elif block.kind == "pre":
            body.append(f"<pre>{html.escape(block.text)}</pre>")
        elif block.kind == "table":
            head = "".join(f"<th>{html.escape(str(h))}</th>" for h in block.headers)
            rows = []
            for index, row in enumerate(block.rows):
                status = block.status[index] if index < len(block.status) else None
                cls = f' class="{status}"' if status else ""
                rows.append(f"<tr{cls}>" + "".join(_cell(c) for c in row) + "</tr>")
            body.append(f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>")
        elif block.kind == "figure":
            data = base64.b64encode(block.image).decode("ascii")
            body.append(
                f"<h3>{html.escape(block.title)}</h3>"
                f'<figure><img alt="{html.escape(block.title)}" src="data:image/png;base64,{data}">'
                f"<figcaption>{html.escape(block.text)}</figcaption></figure>"
            )
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>'
        f"<style>{CSS}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n"
    )


def write_report(report: VerifyReport, out_dir: str | Path, *, write_json: bool = True) -> dict[str, Path]:
    """Write report.json (optionally), report.md with plots/*.png, and the self-contained report.html."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}
    if write_json:
        written["json"] = atomic_write_text(
            out / REPORT_JSON, json.dumps(report.to_dict(), indent=1, sort_keys=False) + "\n"
        )
    blocks = blocks_of(report)
    for block in blocks:
        if block.kind == "figure":
            atomic_write_bytes(out / PLOTS_DIR / block.name, block.image)
    written["md"] = atomic_write_text(out / REPORT_MD, render_markdown(blocks))
    written["html"] = atomic_write_text(out / REPORT_HTML, render_html(blocks))
    return written
