"""The report's figures as PNG bytes (matplotlib on the Agg backend, imported on first use)."""

from __future__ import annotations

import io
import textwrap
from collections.abc import Sequence
from typing import Any

import numpy as np

from vprsnn_export.readout.strategies import SEQUENCE_STRATEGY, STRATEGIES
from vprsnn_export.stats import MeanStd

from ..results import METRICS, RunSummary, VerifiedRun, VerifyReport
from .labels import METRIC_TITLES, row_label, strategy_title


def pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend, imported on first use (it costs ~0.8 s at start-up)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def png(fig: Any) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100, bbox_inches="tight")
    pyplot().close(fig)
    return buffer.getvalue()


def merged(series: Sequence[tuple[str, Any]]) -> list[tuple[str, Any, int]]:
    """``(label, data)`` series with identical data once, labelled "A = B": ``(label, data, first index)``."""
    datas = [data for _, data in series]
    firsts = [(index, data) for index, data in enumerate(datas) if data not in datas[:index]]
    return [(" = ".join(label for label, other in series if other == data), data, index) for index, data in firsts]


def percent(value: MeanStd) -> tuple[float, float]:
    """(mean %, std %) of a fraction's mean ± std (0 where unknown)."""
    return 100 * (value.mean or 0.0), 100 * (value.std or 0.0)


def _series(summary: RunSummary, key: tuple[str, int], metric: str) -> tuple[tuple[int, float, float], ...]:
    """(bits, mean %, std %) of one readout's metric at every bit width that has it."""
    rows = ((bits.bits, bits.row(*key)) for bits in summary.bits)
    return tuple(
        (b, *percent(r.values[metric])) for b, r in rows if r is not None and r.values[metric].mean is not None
    )


def pr_axes(ax: Any, title: str, **title_style: Any) -> None:
    ax.set(xlim=(0, 1.02), ylim=(0, 1.05), xlabel="recall", ylabel="precision")
    ax.set_title(title, **title_style)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower left")


def bars(ax: Any, x: np.ndarray, values: Sequence[tuple[float, float]], width: float, **style: Any) -> None:
    """Bars of (mean, std), with error bars only when a std is > 0 (one network has none)."""
    means, stds = (list(column) for column in zip(*values, strict=True)) if values else ([], [])
    ax.bar(x, means, width, yerr=stds if any(stds) else None, capsize=3, **style)


def plot_metrics(summary: RunSummary, ks: Sequence[int]) -> bytes:
    """Each metric vs bit width, a line per readout over its float value (dashed); with one bit width, bars."""
    plt = pyplot()
    keys = [(s, 1) for s in STRATEGIES] + [("wprob", k) for k in ks if k > 1]
    float_rows = {(r.strategy, r.k): r for r in summary.float}
    fig, axes = plt.subplots(2, 2, figsize=(10, 7))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    bits = sorted({b.bits for b in summary.bits})
    for ax, metric in zip(axes.ravel(), METRICS, strict=True):
        floats = {key: percent(row.values[metric]) for key, row in float_rows.items()}
        series = [(row_label(*key), (_series(summary, key, metric), floats.get(key))) for key in keys]
        if len(bits) == 1:
            shown = [(label, points[0][1:], ref or (0.0, 0.0)) for label, (points, ref) in series if points]
            x = np.arange(len(shown))
            bars(ax, x - 0.2, [ref for *_, ref in shown], 0.4, color="0.75", label="float")
            bars(ax, x + 0.2, [value for _, value, _ in shown], 0.4, color=colours[0], label=f"{bits[0]}-bit")
            ax.set_xticks(x, [label for label, *_ in shown], fontsize=8)
            top = max((max(value[0], ref[0]) for _, value, ref in shown), default=0.0)
            ax.set_ylim(0, min(max(5.0, 1.15 * top), 102.0))
        else:
            for label, (points, ref), index in merged(series):
                colour = colours[index % len(colours)]
                if points:
                    xs, means, stds = zip(*points, strict=True)
                    ax.errorbar(
                        xs, means, yerr=stds, capsize=3, color=colour, label=label, marker="osD^vP*X"[index % 8]
                    )
                if ref is not None:
                    ax.axhline(ref[0], color=colour, linestyle="--", linewidth=1)
            # fewer bits to the right
            ax.set(xticks=bits, xlim=(max(bits) + 0.5, min(bits) - 0.5), xlabel="weight bits (dashed: float)")
        ax.legend(fontsize=7)
        ax.set(title=METRIC_TITLES[metric], ylabel="%")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return png(fig)


def plot_pr(run: VerifiedRun) -> bytes:
    """W+Prob's PR curves per k: float (black) and each bit width; identical curves drawn once, "A = B"."""
    plt = pyplot()
    names = list(run.float.pr_curves)
    fig, axes = plt.subplots(1, len(names), figsize=(5 * len(names), 4.2), squeeze=False)
    cmap = plt.get_cmap("viridis")
    n = max(len(run.bits) - 1, 1)
    for ax, name in zip(axes[0], names, strict=True):
        curves = [("float", run.float.pr_curves[name])]
        curves += [(f"{r.bits}-bit", r.pr_curves[name]) for r in run.bits if name in r.pr_curves]
        series = [(label, (tuple(c.recall), tuple(c.precision))) for label, c in curves]
        for label, (recall, precision), index in merged(series):
            style = {"color": "black", "linewidth": 2} if index == 0 else {"color": cmap((index - 1) / n)}
            ax.step(recall, precision, where="post", label=label, **style)
        pr_axes(ax, name.replace(SEQUENCE_STRATEGY, strategy_title(SEQUENCE_STRATEGY)))
    return png(fig)


def plot_modules(run: VerifiedRun) -> bytes:
    """Per module: whole-route accuracy at k (float and each bit width) and the same-winner share."""
    plt = pyplot()
    results = [result for result in run.bits if result.modules]
    modules = results[0].modules
    x = np.arange(len(modules))
    fig, axes = plt.subplots(2, 1, figsize=(max(6.0, 0.35 * len(modules) + 2), 5.2), sharex=True)
    cmap = plt.get_cmap("viridis")
    n = max(len(results) - 1, 1)
    accuracy = [("float", tuple(100 * m.float_accuracy_k for m in modules))]
    accuracy += [(f"{r.bits}-bit", tuple(100 * m.accuracy_k for m in r.modules)) for r in results]
    winner = [(f"{r.bits}-bit", tuple(100 * m.winner_agreement for m in r.modules)) for r in results]
    for ax, series, first in ((axes[0], accuracy, 1), (axes[1], winner, 0)):
        for label, values, index in merged(series):
            if index < first:  # float: black, open circles, dashed
                ax.plot(x, values, "o--", color="black", markerfacecolor="none", markersize=8, label=label)
            else:
                ax.plot(x, values, ".-", color=cmap((index - first) / n), label=label)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, ncol=len(series), loc="lower center", bbox_to_anchor=(0.5, 1.02))
    axes[0].set_ylabel(f"accuracy k={modules[0].k} %")
    axes[1].set(ylabel="same winner %", xlabel="module (region of consecutive places)")
    axes[1].xaxis.set_major_locator(plt.MaxNLocator(integer=True))  # module numbers, never 0.5
    fig.tight_layout()
    return png(fig)


def window_share(edges: np.ndarray, counts: np.ndarray, x: np.ndarray, width: float) -> np.ndarray:
    """The share of a histogram's values within ``width`` around each ``x`` (uniform within a bin):
    ``share(x) = F(x + width/2) - F(x - width/2)``, F the cumulative share at the edges, interpolated."""
    cdf = np.concatenate([[0.0], np.cumsum(counts)]) / max(float(np.sum(counts)), 1.0)
    return np.interp(x + width / 2, edges, cdf) - np.interp(x - width / 2, edges, cdf)


def plot_weights(run: VerifiedRun) -> bytes:
    """Per bit width: the share of weights on each level q / L (bars) over :func:`window_share` (line)."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(run.bits), figsize=(3.3 * len(run.bits), 3.0), squeeze=False)
    edges = np.asarray(run.float.weights.edges, dtype=np.float64)
    counts = np.asarray(run.float.weights.counts, dtype=np.float64)
    x = np.linspace(edges[0], edges[-1], 401)
    for ax, result in zip(axes[0], run.bits, strict=True):
        levels = result.weight_levels
        top = levels.levels
        share = np.asarray(levels.counts, dtype=np.float64) / max(sum(levels.counts), 1)
        at = np.arange(top + 1) / top
        ax.bar(at, share, width=0.85 / top, color="tab:orange", alpha=0.85, label=f"{result.bits}-bit levels")
        ax.plot(x, window_share(edges, counts, x, 1 / top), color="tab:blue", linewidth=1.2, label="float")
        ax.set_title(f"{result.bits}-bit: {100 * levels.zero_fraction:.1f} % of weights at 0", fontsize=9)
        ax.set(xlabel="weight / scale range", xlim=(-0.08, 1.08))
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=8)
    axes[0, 0].set_ylabel("share of weights")
    axes[0, 0].legend(fontsize=7)
    return png(fig)


def plot_spikes(report: VerifyReport) -> bytes:
    """Left: the agreements vs bit width; right: the per-query count correlations per bit width, pooled."""
    plt = pyplot()
    summary = report.summary
    bits = [b.bits for b in summary.bits]
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    agreements: tuple[tuple[str, list[MeanStd]], ...] = (
        ("same winner per step", [b.winner_agreement for b in summary.bits]),
        ("top-1 agreement W+Prob k=1", [b.top1_agreement["wprob"] for b in summary.bits]),
        ("mean count correlation", [b.count_correlation for b in summary.bits]),
    )
    series = [(label, tuple(zip(*map(percent, values), strict=True))) for label, values in agreements]
    if len(bits) == 1:
        shown = merged(series)
        x = np.arange(len(shown))
        bars(left, x, [(m[0], sd[0]) for _, (m, sd), _ in shown], 0.6)
        left.set_xticks(x, [textwrap.fill(label, 18) for label, _, _ in shown], fontsize=8)
        left.set_xlabel(f"{bits[0]}-bit")
    else:
        for label, (means, stds), _ in merged(series):
            left.errorbar(bits, means, yerr=stds, marker="o", capsize=3, label=label)
        left.set(xticks=sorted(bits), xlim=(max(bits) + 0.5, min(bits) - 0.5), xlabel="weight bits")
        left.legend(fontsize=8, loc="lower left")
    left.set(ylabel="%", ylim=(0, 102))
    left.grid(alpha=0.3)
    pooled = [
        [c for run in report.runs for r in run.bits if r.bits == b for c in r.spike_level.count_correlation]
        for b in bits
    ]
    right.boxplot(pooled)
    right.set_xticks(range(1, len(bits) + 1), [str(b) for b in bits])
    right.set(xlabel="weight bits", ylabel="per-query spike-count correlation", ylim=(-0.05, 1.05))
    right.grid(alpha=0.3)
    return png(fig)


def plot_precision_recall(
    recall: np.ndarray, precision: np.ndarray, target: float, chosen: tuple[float, float, float] | None, title: str
) -> bytes:
    """A calibration curve (``localize --calibrate``), the target dashed and the chosen point marked."""
    fig, ax = pyplot().subplots(figsize=(5, 4))
    ax.plot(recall, precision, ".-", color="black", label="calibration (a point per threshold)")
    ax.axhline(target, color="tab:red", linestyle="--", linewidth=1, label="target precision")
    if chosen is not None:
        ax.plot([chosen[0]], [chosen[1]], "o", color="tab:red", label=f"operating point ({chosen[2]:.4g})")
    pr_axes(ax, title, fontsize=10)
    return png(fig)
