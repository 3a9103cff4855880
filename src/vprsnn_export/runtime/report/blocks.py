"""The report as a format-neutral list of blocks: headings, paragraphs, tables, figures."""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import dataclass

from vprsnn_export.readout.strategies import STRATEGIES

from ..results import METRICS, RunSummary, VerifiedRun, VerifyReport
from ..verify.checks import TOLERANCE_MEANING
from .labels import (
    METRIC_TITLES,
    PAIRED_COLUMNS,
    VERDICT_COLUMNS,
    data_label,
    data_note,
    exact_counts,
    ms,
    network_label,
    paired_cells,
    points,
    row_label,
    shown_paired,
    signed_pct,
    strategy_title,
    tolerance_counts,
    tolerance_differences,
    verdict,
    verdict_cells,
    verdict_counts,
)
from .plots import plot_metrics, plot_modules, plot_pr, plot_spikes, plot_weights

#: Characters that end or break a line (and other control characters): a stored string holding one could
#: start a line of its own in report.md (a forged heading), so each becomes a space.
LINE_BREAKING = re.compile(r"[\x00-\x1f\x7f-\x9f\u2028\u2029]")


def one_line(text: object) -> str:
    """``text`` on one line: every line break or control character replaced by a space."""
    return LINE_BREAKING.sub(" ", str(text))


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
                if not check.passed and check.check in POINT_CHECKS:
                    value, limit = points(check.check, check.value), points(check.check, check.applied_limit)
                    lines.append(f"{network}, {result.bits} bits: {check.what} = {value} (limit {limit})")
            for paired in result.paired:
                if paired.verdict == "fails":
                    cells = paired_cells(paired)
                    lines.append(
                        f"{network}, {result.bits} bits: {cells['metric']} {cells['readout']} Δ {cells['difference']} "
                        f"pts, interval {cells['interval']} beyond the {cells['limit']}-point limit"
                    )
    return lines


#: Tolerances judged on one measured number (the metric tolerances are judged on the paired table).
POINT_CHECKS = ("winner_agreement", "top1_agreement", "saturations")


def conclusion(report: VerifyReport) -> str:
    """What the verdict means, in one sentence."""
    n_runs = len(report.runs)
    if report.verdict == "fails":
        return f"{n_runs - report.n_passed} of {n_runs} network(s) fail a check at some bit width"
    if report.verdict == "undecided":
        n = sum(c.verdict == "undecided" for run in report.runs for r in run.bits for c in r.paired)
        return (
            f"nothing fails, but {n} paired check(s) straddle their tolerance: on these queries the difference "
            "cannot be told from the paired sampling noise (the paired table says how many queries would decide)"
        )
    return "every check holds at every bit width (each paired interval lies inside its tolerance)"


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
                f"**Verdict: {report.verdict.upper()}** — {conclusion(report)}. Query traversal "
                f"**{first.query}**, {first.n_queries} queries"
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
    blocks += verdict_blocks(report)
    blocks += paired_blocks(report)
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


def verdict_blocks(report: VerifyReport) -> list[Block]:
    """Per network and bit width, the columns the terminal shows too (:data:`.labels.VERDICT_COLUMNS`)."""
    tolerances = report.settings.get("tolerances", {})
    results = [(index, run, result) for index, run in enumerate(report.runs) for result in run.bits]
    rows = [[verdict_cells(run, index, result)[key] for key, _ in VERDICT_COLUMNS] for index, run, result in results]
    limits = ", ".join(f"{key} {value:g}" for key, value in tolerances.items() if value is not None)
    return [
        Block("h2", "Verdict per bit width"),
        Block(
            "table",
            headers=[title for _, title in VERDICT_COLUMNS],
            rows=rows,
            status=[VERDICT_STATUS.get(result.verdict) for _, _, result in results],
        ),
        Block(
            "p",
            f"Tolerances: {limits or 'none'} (drops from float, in fractions; see docs/verify.md). "
            "Δ = quantised - float, in percentage points; negative is worse. Exact rows: implementations that "
            "must agree bit for bit; tolerance rows: float consumers judged on their stated decision agreement.",
        ),
    ]


#: A verdict's row colour in the HTML tables.
VERDICT_STATUS = {"holds": "pass", "fails": "fail"}


def paired_blocks(report: VerifyReport) -> list[Block]:
    """The paired table: per network and bit width every judged metric (and every readout's accuracy) with its
    flips, the difference, its interval and the verdict."""
    stats = report.settings.get("statistics") or {}
    rows, status = [], []
    for index, run in enumerate(report.runs):
        for result in run.bits:
            for check in shown_paired(result.paired):
                cells = paired_cells(check)
                rows.append([network_label(run, index), f"{result.bits}", *(cells[k] for k, _ in PAIRED_COLUMNS)])
                status.append(VERDICT_STATUS.get(check.verdict or ""))
    if not rows:
        return []
    counts = "; ".join(
        f"{network_label(run, i)}, {r.bits} bits: {verdict_counts(r.paired) or 'nothing judged'}"
        for i, run in enumerate(report.runs)
        for r in run.bits
    )
    return [
        Block("h2", "Paired verdict"),
        Block(
            "p",
            "Float and deployed see the same spikes, so each query is a pair. Flips: queries the float network "
            "gets right and the deployed one wrong / the reverse. Δ = deployed - float, in points, with its "
            f"{100 * float(stats.get('confidence', 0.95)):g} % paired interval: exact McNemar for accuracy at k=1, "
            f"the paired bootstrap otherwise ({stats.get('resamples', '?')} resamples, seed {stats.get('seed', '?')};"
            " blocks of k consecutive queries for k > 1). A check **holds** when the whole interval lies inside "
            "its drop limit, **fails** when it lies entirely beyond it, and is **undecided** when it straddles "
            "the limit (with roughly how many queries would decide it); a float R@100P of 0 is **not judged**. "
            "Checks without a limit are reported only. " + counts + ".",
        ),
        Block(
            "table",
            headers=["network", "bits", *(title for _, title in PAIRED_COLUMNS)],
            rows=rows,
            status=status,
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
                    exact_counts([cross]),
                    tolerance_counts([cross]),
                    tolerance_differences(cross),
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
            "difference fails. Tolerance rows (float NIR consumers + the file's readout rule, judged on their "
            "stated decision agreement) are counted on their own, with their measured difference: never as "
            "exact.",
        ),
        Block(
            "table",
            headers=[
                "network",
                "bits",
                "exact rows identical",
                "tolerance rows within",
                "tolerance rows: decisions that differ",
                "verdict",
                "reference-stepper queries",
                "implementations",
            ],
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
                data_label(run.checkpoint_data),
                f"{data_label(report.settings)}, '{run.query}'",
                f"{run.n_queries}",
                str(run.export_dir or "-"),
            ]
        )
    if report.command:
        text = " ".join(map(one_line, report.command))
    else:
        text = "\n".join(" ".join(map(one_line, c)) for c in report.commands or () if c) or "-"
    return [
        Block("h2", "Networks"),
        Block(
            "table",
            headers=["network", "seed", "checkpoint sha256", "trained on", "evaluated on", "queries", "exports"],
            rows=rows,
        ),
        Block("h2", "Provenance"),
        Block("pre", "command: " + text),
        Block("pre", json.dumps(dict(report.settings), indent=2, sort_keys=True), title="settings"),
        Block("pre", json.dumps(dict(report.runs[0].config), indent=2, sort_keys=True), title="config (first network)"),
        Block("pre", json.dumps(dict(report.versions), indent=2, sort_keys=True), title="versions"),
    ]
