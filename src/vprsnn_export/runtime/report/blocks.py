"""The report as a format-neutral list of blocks: headings, paragraphs, tables, figures."""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

from vprsnn_export.readout.strategies import STRATEGIES

from ..measurements import ConformanceResult
from ..results import METRICS, BitsResult, RunSummary, VerifiedRun, VerifyReport
from ..verify.checks import TOLERANCE_MEANING
from ..verify.paired import PAIRED_TOLERANCES
from .labels import (
    METRIC_TITLES,
    PAIRED_COLUMNS,
    VERDICT_COLUMNS,
    data_label,
    exact_counts,
    ms,
    network_label,
    paired_cells,
    points,
    results,
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

#: A verdict's row colour in the HTML tables.
VERDICT_STATUS = {"holds": "pass", "fails": "fail"}


def one_line(text: object) -> str:
    """``text`` on one line: every line break or control character replaced by a space."""
    return LINE_BREAKING.sub(" ", str(text))


#: A table's columns: title -> the cell of an item (a row).
Columns = dict[str, Callable[[Any], str]]


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


def table(columns: Mapping[str, Callable[[Any], str]], items: Iterable[Any], status: Callable | None = None) -> Block:
    """One row per item, one column per ``title: cell(item)``; ``status(item)`` colours its row."""
    items = list(items)
    rows = [[cell(item) for cell in columns.values()] for item in items]
    return Block("table", headers=list(columns), rows=rows, status=[status(i) for i in items] if status else ())


#: The first columns of a table with a row per network, bit width and item (:func:`per_result`).
WHERE: Columns = {"network": lambda i: i[0], "bits": lambda i: str(i[1].bits)}


def per_result(report: VerifyReport, items: Callable[[BitsResult], Iterable[Any]]) -> list[tuple[str, BitsResult, Any]]:
    """``(network label, result, item)`` of every network, bit width and item of ``items(result)``, in order."""
    return [(label, result, item) for label, _, result in results(report) for item in items(result)]


def figure(title: str, name: str, image: bytes, caption: str) -> Block:
    return Block("figure", title=title, name=name, image=image, text=caption)


def section(title: str, *parts: Block | str) -> list[Block]:
    """A section: its heading, then its parts in order (a string is a paragraph)."""
    return [Block("h2", title), *(Block("p", part) if isinstance(part, str) else part for part in parts)]


def failed_points(result: BitsResult, sep: str = " =") -> list[str]:
    """A width's cross-implementation differences and missed point limits (``what{sep} value (limit L)``): the
    tolerances judged on one measured number (the metric tolerances are judged on the paired table)."""
    cross = result.cross_implementation
    failed = [] if cross.passed else [f"{cross.n_failed} cross-implementation differences"]
    return failed + [
        f"{c.what}{sep} {points(c.check, c.value)} (limit {points(c.check, c.applied_limit)})"
        for c in result.tolerance_checks
        if not c.passed and c.check not in PAIRED_TOLERANCES
    ]


def failure_lines(report: VerifyReport) -> list[str]:
    """Each failed check, named with its network and bit width: what the verdict line's FAIL means."""
    lines = []
    for label, run, result in results(report):
        where = f"{label if run.label else f'network {label}'}, {result.bits} bits"
        lines += [f"{where}: {line}" for line in failed_points(result)]
        for cells in (paired_cells(c) for c in result.paired if c.verdict == "fails"):
            lines.append(
                f"{where}: {cells['metric']} {cells['readout']} Δ {cells['difference']} pts, interval "
                f"{cells['interval']} beyond the {cells['limit']}-point limit"
            )
    return lines


def conclusion(report: VerifyReport) -> str:
    """What the verdict means, in one sentence, and the float networks that do not recognise places."""
    n_runs = len(report.runs)
    text = "every check holds at every bit width (each paired interval lies inside its tolerance)"
    if report.verdict == "fails":
        text = f"{n_runs - report.n_passed} of {n_runs} network(s) fail a check at some bit width"
    elif report.verdict == "undecided":
        n = sum(c.verdict == "undecided" for run in report.runs for r in run.bits for c in r.paired)
        text = (
            f"nothing fails, but {n} paired check(s) straddle their tolerance: on these queries the difference "
            "cannot be told from the paired sampling noise (the paired table says how many queries would decide)"
        )
    if report.degenerate:
        text += f"; BUT the float network is degenerate ({report.degenerate}): a width that holds keeps nothing worth keeping"
    return text


def blocks_of(report: VerifyReport) -> list[Block]:
    summary, runs = report.summary, report.runs
    first, n_runs = runs[0], len(runs)
    ks = first.ks
    networks = f"mean ± std over {n_runs} independently trained networks" if n_runs > 1 else "one network"
    seconds = f" in {report.seconds:.0f} s" if report.seconds else ""
    data = f" from {data_label(report.settings)}" if report.settings.get("data") else ""
    blocks = [
        Block("h1", "vprsnn-export verification report"),
        Block(
            "p",
            f"**Verdict: {report.verdict.upper()}** — {conclusion(report)}. Query traversal **{first.query}**, "
            f"{first.n_queries} queries{data}; {networks}. Generated {report.created}{seconds}.",
        ),
    ]
    if failures := failure_lines(report):
        blocks.append(Block("p", "**Failed:** " + "; ".join(failures) + "."))
    if report.settings_differ:
        differ = ", ".join(report.settings_differ)
        blocks.append(
            Block("p", f"Combined reports whose settings differ in: {differ} (settings shown are the first report's).")
        )
    which = f"; network {first.label or 1} of {n_runs}." if n_runs > 1 else "."
    return [
        *blocks,
        *verdict_blocks(report),
        *paired_blocks(report),
        *metric_blocks(summary, ks),
        figure(
            "Metrics vs weight bit width",
            "metrics_vs_bits.png",
            plot_metrics(summary, ks),
            "Each metric vs bit width; the float network's value is the dashed line of the same colour"
            + (" (mean ± std over networks)." if n_runs > 1 else "."),
        ),
        figure(
            "Precision-recall curves",
            "pr_curves.png",
            plot_pr(first),
            f"W+Prob at k=1 and k={max(ks)}, float (black) vs each bit width{which}",
        ),
        *spike_blocks(summary, runs),
        figure(
            "Spike-count agreement",
            "spike_agreement.png",
            plot_spikes(report),
            "Left: fraction of time steps with the float winner, top-1 agreement and mean per-query "
            "spike-count correlation vs bit width. Right: distribution of the per-query correlation "
            "of the float and quantised spike-count vectors (all networks pooled).",
        ),
        *decision_blocks(summary, ks),
        *module_blocks(first, n_runs),
        *cross_blocks(report),
        *quantisation_blocks(first),
        figure(
            "Weight histograms",
            "weight_histograms.png",
            plot_weights(first),
            f"Float weights divided by their scale range ({first.float.weights.normalised_by}): the share of "
            "weights on each quantised level q / L, L = 2^b - 1 (bars), and the share of float weights within "
            "1 / L around each point (line).",
        ),
        *tolerance_blocks(report),
        *provenance_blocks(report),
    ]


def verdict_blocks(report: VerifyReport) -> list[Block]:
    """Per network and bit width, the columns the terminal shows too (:data:`.labels.VERDICT_COLUMNS`)."""
    cells = [(verdict_cells(*item), item[2]) for item in results(report)]
    columns: Columns = {title: partial(lambda key, item: item[0][key], key) for key, title in VERDICT_COLUMNS}
    limits = ", ".join(f"{k} {v:g}" for k, v in report.settings.get("tolerances", {}).items() if v is not None)
    return section(
        "Verdict per bit width",
        table(columns, cells, lambda item: VERDICT_STATUS.get(item[1].verdict)),
        f"Tolerances: {limits or 'none'} (drops from float, in fractions; see docs/verify.md). "
        "Δ = quantised - float, in percentage points; negative is worse. Exact rows: implementations that "
        "must agree bit for bit; tolerance rows: float consumers judged on their stated decision agreement.",
    )


def paired_blocks(report: VerifyReport) -> list[Block]:
    """The paired table: per network and bit width every shown check's flips, difference, interval and verdict."""
    checks = per_result(report, lambda r: shown_paired(r.paired))
    if not checks:
        return []
    stats = report.settings.get("statistics") or {}
    counts = "; ".join(
        f"{n}, {r.bits} bits: {verdict_counts(r.paired) or 'nothing judged'}" for n, _, r in results(report)
    )
    columns = WHERE | {title: partial(lambda key, i: paired_cells(i[2])[key], key) for key, title in PAIRED_COLUMNS}
    return section(
        "Paired verdict",
        "Float and deployed see the same spikes, so each query is a pair. Flips: queries the float network "
        "gets right and the deployed one wrong / the reverse. Δ = deployed - float, in points, with its "
        f"{100 * float(stats.get('confidence', 0.95)):g} % paired interval: exact McNemar for accuracy at k=1, "
        f"the paired bootstrap otherwise ({stats.get('resamples', '?')} resamples, seed {stats.get('seed', '?')};"
        " blocks of k consecutive queries for k > 1). A check **holds** when the whole interval lies inside "
        "its drop limit, **fails** when it lies entirely beyond it, and is **undecided** when it straddles "
        "the limit (with roughly how many queries would decide it); a float R@100P of 0 is **not judged**. "
        f"Checks without a limit are reported only. {counts}.",
        table(columns, checks, lambda i: VERDICT_STATUS.get(i[2].verdict or "")),
    )


def metric_blocks(summary: RunSummary, ks: Sequence[int]) -> list[Block]:
    float_rows = {(r.strategy, r.k): r for r in summary.float}
    keys = [key for key in [(s, 1) for s in STRATEGIES] + [("wprob", k) for k in ks if k > 1] if key in float_rows]

    def cell(row: Any, metric: str) -> str:
        delta = "-" if row is None or row.delta is None else ms(row.delta[metric], signed=True)
        return "-" if row is None else f"{ms(row.values[metric])} ({delta})"

    blocks = [Block("h2", "Metric level")]
    for metric in METRICS:
        columns: Columns = {
            "readout": lambda key: row_label(*key),
            "float %": partial(lambda m, key: ms(float_rows[key].values[m]), metric),
        }
        columns |= {
            f"{b.bits}-bit % (Δ)": partial(lambda b, m, key: cell(b.row(*key), m), b, metric) for b in summary.bits
        }
        blocks += [Block("h3", METRIC_TITLES[metric]), table(columns, keys)]
    return blocks


def spike_blocks(summary: RunSummary, runs: Sequence[VerifiedRun]) -> list[Block]:
    columns = {
        "bits": lambda b: str(b.bits),
        "same winner %": lambda b: ms(b.winner_agreement, digits=2),
        "count correlation": lambda b: ms(b.count_correlation, percent=False, digits=3),
        "spike ratio": lambda b: ms(b.spike_ratio, percent=False, digits=3),
        "saturations": lambda b: ms(b.saturations, percent=False, digits=0),
    }
    # step-level checks on the first queries only (a large network)
    cut = [run for run in runs if run.recorded_queries is not None and run.recorded_queries < run.n_queries]
    recorded = (
        f" Same winner, the per-module agreement and the exported files' rasters are compared on the first "
        f"{cut[0].recorded_queries} of {cut[0].n_queries} queries (a recorded raster of every query would "
        "not fit in memory); counts, correlations, saturations and every metric use all queries."
        if cut
        else ""
    )
    return section(
        "Spike level",
        "Same float and quantised input spikes; per time step, do both networks emit the same spike (the "
        "WTA winner, or both silent)? Per query, how well do the two spike-count vectors correlate? "
        "Spike ratio = quantised / float total spikes. Saturations: voltage clips on the queries." + recorded,
        table(columns, summary.bits),
    )


def decision_blocks(summary: RunSummary, ks: Sequence[int]) -> list[Block]:
    columns: Columns = {"bits": lambda b: str(b.bits)}
    columns |= {
        f"top-1 {strategy_title(s)} %": partial(lambda s, b: ms(b.top1_agreement.get(s)), s) for s in STRATEGIES
    }
    columns["W+Prob TV distance"] = lambda b: ms(b.wprob_tv_mean, percent=False, digits=3)
    columns |= {f"agreement k={k} %": partial(lambda k, b: ms(b.aggregated_agreement.get(k)), k) for k in ks if k > 1}
    return section(
        "Decision level",
        "Top-1 agreement: share of queries where the quantised network picks the same place as the float "
        "one (or both reject). TV distance: mean total variation between the float and quantised W+Prob "
        "distributions (0 = identical, 1 = disjoint). Aggregated: the same agreement after k-frame "
        "sequence aggregation.",
        table(columns, summary.bits),
    )


def cross_blocks(report: VerifyReport) -> list[Block]:
    def implementations(cross: ConformanceResult) -> str:
        skipped = "; skipped: " + ", ".join(f"{k} ({v})" for k, v in cross.skipped.items()) if cross.skipped else ""
        return "; ".join(sorted({c.check.split(":")[0] for c in cross.comparisons})) + skipped

    columns = WHERE | {
        "exact rows identical": lambda i: exact_counts([i[2]]),
        "tolerance rows within": lambda i: tolerance_counts([i[2]]),
        "tolerance rows: decisions that differ": lambda i: tolerance_differences(i[2]),
        "verdict": lambda i: verdict(i[2].passed),
        "reference-stepper queries": lambda i: str(i[2].reference_queries),
        "implementations": lambda i: implementations(i[2]),
    }
    blocks = section(
        "Cross-implementation (exact)",
        "Integer simulator vs ONNX on onnxruntime vs the NIR and Loihi-style files read back and re-run vs "
        "the slow reference stepper (on the first queries only: it is a per-neuron Python loop). Rasters, "
        "counts, candidate counts, final voltages, saturations and every integer array are compared bit "
        "for bit; the ONNX W+Prob head must give identical decisions (float64, |diff| <= 1e-12). Any "
        "difference fails. Tolerance rows (float NIR consumers + the file's readout rule, judged on their "
        "stated decision agreement) are counted on their own, with their measured difference: never as "
        "exact.",
        table(
            columns, per_result(report, lambda r: [r.cross_implementation]), lambda i: "pass" if i[2].passed else "fail"
        ),
    )
    if failures := per_result(report, lambda r: r.cross_implementation.failures):
        columns = WHERE | {"check": lambda f: f[2].check, "detail": lambda f: f[2].detail}
        blocks += [Block("h3", "Differences found"), table(columns, failures, lambda _: "fail")]
    return blocks


def module_blocks(run: VerifiedRun, n_runs: int) -> list[Block]:
    """An ensemble's per-module table (whole-route accuracy on each region's queries) and its plot."""
    with_modules = [result for result in run.bits if result.modules]
    if not with_modules:
        return []
    first = with_modules[0].modules
    k = first[0].k
    columns: Columns = {
        "module": lambda i: str(first[i].module),
        "places": lambda i: f"{first[i].first_place}-{first[i].last_place}",
        "queries": lambda i: str(first[i].n_queries),
        "float k=1 %": lambda i: f"{100 * first[i].float_accuracy:.1f}",
        f"float k={k} %": lambda i: f"{100 * first[i].float_accuracy_k:.1f}",
    }
    worst = []
    for r in run.bits:
        columns[f"{r.bits}-bit k={k} % (Δ)"] = partial(
            lambda r, i: f"{100 * r.modules[i].accuracy_k:.1f} ({signed_pct(r.modules[i].delta_k)})", r
        )
        columns[f"{r.bits}-bit same winner %"] = partial(lambda r, i: f"{100 * r.modules[i].winner_agreement:.1f}", r)
        low = min(r.modules, key=lambda m: (m.delta_k, m.winner_agreement))
        worst.append(
            f"{r.bits}-bit: module {low.module} (places {low.first_place}-{low.last_place}, "
            f"{signed_pct(low.delta_k)} pts at k={k}, {100 * low.winner_agreement:.1f} % same winner)"
        )
    which = f" (network {run.label or 1} of {n_runs})" if n_runs > 1 else ""
    return section(
        f"Modules of the ensemble{which}",
        f"{len(first)} modules. Accuracy is the whole-route W+Prob decision (every module's neurons, every "
        "place) scored on the queries whose true place lies in the module's region; same winner: the share "
        "of time steps on which the module's WTA picks the float module's winner. The module that degrades "
        "most: " + "; ".join(worst) + ".",
        table(columns, range(len(first))),
        figure(
            "Accuracy per module",
            "modules.png",
            plot_modules(run),
            f"Whole-route W+Prob accuracy at k={k} on each module's region, float (black) vs each bit width.",
        ),
    )


def quantisation_blocks(run: VerifiedRun) -> list[Block]:
    columns = {
        "bits": lambda r: str(r.bits),
        "scales": lambda r: (
            ("per-neuron" if r.quantisation.per_neuron else "per-tensor") + f", {r.quantisation.scale_method}"
        ),
        "weight rel. RMSE": lambda r: f"{r.quantisation.weight_relative_rmse or 0:.4f}",
        "clipped weights": lambda r: str(r.quantisation.weights_clipped),
        "max threshold error %": lambda r: f"{100 * (r.quantisation.threshold_max_relative_error or 0):.3f}",
        "weights at 0 %": lambda r: f"{100 * r.weight_levels.zero_fraction:.1f}",
        "max current": lambda r: str(r.quantisation.max_current),
        "calibration": lambda r: str(r.quantisation.calibration),
        "calibration saturations": lambda r: str(r.quantisation.calibration_saturations),
    }
    return section("Quantisation", table(columns, run.bits))


def tolerance_blocks(report: VerifyReport) -> list[Block]:
    def limit(check: Any) -> str:
        shown = f"{check.applied_limit:g}" if check.check == "saturations" else f"{100 * check.applied_limit:.2f}"
        return shown + (f" (1 query; set {100 * check.limit:.2f})" if check.applied_limit != check.limit else "")

    columns = WHERE | {
        "check": lambda i: i[2].what,
        "value": lambda i: str(i[2].value) if i[2].check == "saturations" else f"{100 * i[2].value:.2f}",
        "limit": lambda i: limit(i[2]),
        "verdict": lambda i: verdict(i[2].passed),
    }
    meaning = "; ".join(f"{k}: {TOLERANCE_MEANING[k]}" for k in TOLERANCE_MEANING)
    return section(
        "Tolerance checks",
        "Values and limits in percentage points (drops) or percent (agreements). A metric moves in steps of "
        "one query (100/Q points), so a drop limit below query_slack queries is raised to it. "
        f"Keys — {meaning}.",
        table(columns, per_result(report, lambda r: r.tolerance_checks), lambda i: "pass" if i[2].passed else "fail"),
    )


def summarised(config: dict) -> dict:
    """A config for reading: a learnt ``encoder.input_gain`` as its size and range, not 1568 numbers."""
    gain = config.get("encoder", {}).get("input_gain") if isinstance(config.get("encoder"), dict) else None
    if not gain:
        return config
    text = f"{len(gain)} learnt gains from {min(gain):.3g} to {max(gain):.3g} (mean {sum(gain) / len(gain):.3g})"
    return {**config, "encoder": {**config["encoder"], "input_gain": text}}


def provenance_blocks(report: VerifyReport) -> list[Block]:
    columns = {
        "network": lambda i: network_label(report.runs[i], i),
        "seed": lambda i: str(report.runs[i].seed),
        "checkpoint sha256": lambda i: report.runs[i].checkpoint_sha256[:16],
        "trained on": lambda i: data_label(report.runs[i].checkpoint_data),
        "evaluated on": lambda i: f"{data_label(report.settings)}, '{report.runs[i].query}'",
        "queries": lambda i: str(report.runs[i].n_queries),
        "exports": lambda i: str(report.runs[i].export_dir or "-"),
    }
    if any(run.checkpoint_data.get("adaptation") for run in report.runs):  # train --adapt-from
        columns["adaptation"] = lambda i: report.runs[i].checkpoint_data.get("adaptation") or "none"
    if report.command:
        text = " ".join(map(one_line, report.command))
    else:
        text = "\n".join(" ".join(map(one_line, c)) for c in report.commands or () if c) or "-"

    def dump(title: str, data: Mapping) -> Block:
        return Block("pre", json.dumps(summarised(dict(data)), indent=2, sort_keys=True), title=title)

    return [
        Block("h2", "Networks"),
        table(columns, range(len(report.runs))),
        Block("h2", "Provenance"),
        Block("pre", "command: " + text),
        dump("settings", report.settings),
        dump("config (first network)", report.runs[0].config),
        dump("versions", report.versions),
    ]
