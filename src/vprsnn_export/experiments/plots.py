"""Small matplotlib helpers (Agg backend, files written atomically)."""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from vprsnn_export.fileio import atomic_write_bytes  # noqa: E402


def save_figure(fig, path: Path) -> Path:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return atomic_write_bytes(path, buffer.getvalue())


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
    """One line with error bars per series: series[label] = (means, stds)."""
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for label, (mean, std) in series.items():
        ax.errorbar(x, mean, yerr=std, marker="o", capsize=3, label=label)
    for label, value in (baselines or {}).items():
        ax.axhline(value, linestyle="--", linewidth=1, color="grey", label=label)
    if log_x:
        ax.set_xscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return save_figure(fig, path)


def route_plot(path: Path, *, ks, curves: dict, modules: dict, module_size: int) -> Path:
    """Left: accuracy vs k per curve (curves[label] = accuracies). Right: accuracy per module along the route
    (modules[label] = accuracies, one per module)."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    for label, values in curves.items():
        left.plot(ks, values, marker="o", label=label, linestyle="--" if label.startswith("SAD") else "-")
    left.set_xlabel("sequence length k (frames)")
    left.set_ylabel("accuracy % (whole route)")
    left.set_title("Whole route: W+Prob vs SAD")
    left.set_xticks(list(ks))
    left.grid(alpha=0.3)
    left.legend(fontsize=8)
    for label, values in modules.items():
        right.plot(range(len(values)), values, marker=".", label=label)
    right.set_xlabel(f"module ({module_size} places each, along the route)")
    right.set_ylabel("accuracy % (W+Prob, k=1)")
    right.set_title("Per module, first seed")
    right.grid(alpha=0.3)
    right.legend(fontsize=8)
    return save_figure(fig, path)
