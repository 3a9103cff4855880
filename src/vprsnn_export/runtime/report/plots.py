"""The report's figures as PNG bytes (matplotlib on the Agg backend, imported on first use)."""

from __future__ import annotations

import io
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


def plot_precision_recall(
    recall: np.ndarray, precision: np.ndarray, target: float, chosen: tuple[float, float, float] | None, title: str
) -> bytes:
    """A calibration curve (``localize --calibrate``): precision vs recall, a point per threshold, the target
    precision dashed and the chosen (recall, precision, threshold) marked."""
    fig, ax = pyplot().subplots(figsize=(5, 4))
    ax.plot(recall, precision, ".-", color="black", label="calibration (a point per threshold)")
    ax.axhline(target, color="tab:red", linestyle="--", linewidth=1, label="target precision")
    if chosen is not None:
        ax.plot([chosen[0]], [chosen[1]], "o", color="tab:red", label=f"operating point ({chosen[2]:.4g})")
    ax.set(xlim=(0, 1.02), ylim=(0, 1.05), xlabel="recall", ylabel="precision")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower left")
    return png(fig)
