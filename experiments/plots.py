"""Small matplotlib helpers (Agg backend, files written atomically)."""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib import ticker  # noqa: E402

from vprsnn_export.io.fileio import atomic_write_bytes  # noqa: E402


def save_figure(fig, path: Path) -> Path:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return atomic_write_bytes(path, buffer.getvalue())


MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")


def marker_size(index: int, largest: float = 9.0, step: float = 1.1) -> float:
    """Each later series' markers a little smaller, so a series drawn over a nearly equal one leaves the
    earlier one's marker showing around it."""
    return max(largest - step * index, 3.0)


def merge_identical(series: dict) -> dict:
    """Series with equal values drawn once, labelled "A = B": otherwise the later one hides the earlier
    one exactly and the legend names a line nobody can see. Values are compared as given (any nesting)."""
    merged: dict = {}
    for label, values in series.items():
        key = repr(values)
        match = next((name for name, other in merged.items() if repr(other) == key), None)
        if match is None:
            merged[label] = values
        else:
            merged[f"{match} = {label}"] = merged.pop(match)
    return merged


def outside_legend(ax) -> None:
    """The legend to the right of the axes, where it covers no point (the figure grows to fit it)."""
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)


def spaced(x, log: bool, gap: float = 0.07) -> list:
    """The values of ``x`` (sorted) whose labels do not collide: a value is kept when it lies at least
    ``gap`` of the axis span (in log10 units on a log axis) beyond the last kept one."""
    values = sorted(set(x))
    position = np.log10(values) if log else np.asarray(values, dtype=float)
    span = float(position[-1] - position[0]) or 1.0
    kept = [0]
    for index in range(1, len(values)):
        if (position[index] - position[kept[-1]]) / span >= gap:
            kept.append(index)
    return [values[i] for i in kept]


def data_ticks(ax, x, log: bool = False) -> None:
    """Ticks at the measured x values only (those whose labels do not collide: :func:`spaced`), written
    as plain numbers; no minor ticks (a log axis labels 3x10^1 ... otherwise, and they overlap)."""
    ticks = spaced(x, log)
    ax.xaxis.set_minor_locator(ticker.NullLocator())
    ax.set_xticks(ticks, [f"{v:g}" for v in ticks])


def line_plot(
    path: Path,
    x,
    series: dict,
    *,
    xlabel: str,
    ylabel: str,
    title: str,
    log_x: bool = False,
    baselines: dict | None = None,
) -> Path:
    """One line with error bars per series: series[label] = (means, stds); identical series are one line
    (:func:`merge_identical`), each with its own marker; the legend sits outside the axes."""
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for index, (label, (mean, std)) in enumerate(merge_identical(series).items()):
        marker = MARKERS[index % len(MARKERS)]
        ax.errorbar(x, mean, yerr=std, marker=marker, markersize=marker_size(index, 6.5, 0.4), capsize=3, label=label)
    styles = ("--", ":", "-.", (0, (5, 1, 1, 1)))
    for index, (label, value) in enumerate(merge_identical(baselines or {}).items()):
        ax.axhline(value, linestyle=styles[index % len(styles)], linewidth=1, color="grey", label=label)
    if log_x:
        ax.set_xscale("log")
    data_ticks(ax, x, log_x)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    outside_legend(ax)
    return save_figure(fig, path)


def route_plot(path: Path, *, ks, curves: dict, modules: dict, module_size: int) -> Path:
    """Left: accuracy vs k per curve (curves[label] = accuracies). Right: accuracy per module along the route
    (modules[label] = accuracies, one per module). Identical curves are one line (:func:`merge_identical`)."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.2))
    for index, (label, values) in enumerate(merge_identical(curves).items()):
        style = "--" if label.startswith("SAD") else "-"
        marker = MARKERS[index % len(MARKERS)]
        left.plot(ks, values, marker=marker, markersize=marker_size(index), label=label, linestyle=style)
    left.set_xlabel("sequence length k (frames)")
    left.set_ylabel("accuracy % (whole route)")
    left.set_title("Whole route: W+Prob vs SAD")
    left.set_xticks(list(ks))
    left.grid(alpha=0.3)
    left.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)
    for index, (label, values) in enumerate(merge_identical(modules).items()):
        marker = MARKERS[index % len(MARKERS)]
        right.plot(range(len(values)), values, marker=marker, markersize=marker_size(index, 5.0), label=label)
    right.xaxis.set_major_locator(ticker.MaxNLocator(integer=True))
    right.set_xlabel(f"module ({module_size} places each, along the route)")
    right.set_ylabel("accuracy % (W+Prob, k=1)")
    right.set_title("Per module, first seed")
    right.grid(alpha=0.3)
    right.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)
    return save_figure(fig, path)
