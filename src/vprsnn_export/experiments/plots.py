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
