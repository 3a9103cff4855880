"""A declared grid of config variants over seeds, on the subset and on consecutive places, beside SAD and cosine.

Each variant is a preset plus dotted config overrides (``--grid NAME=PRESET[,KEY=VALUE...]``).
Keys under ``assignment.`` only change the readout: variants that differ only there share one
trained network per (selection, seed), and their readouts are computed from the same query counts.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from vprsnn_export.config import PRESETS, AssignmentConfig, Config, preset
from vprsnn_export.device import resolve_device
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.readout.scoring import Readout
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.evaluation import Evaluation, evaluate_float
from vprsnn_export.stats import mean_std

from .common import Settings, Variant, load, pct, provenance, summarise_rows, trained_checkpoint
from .plots import save_figure

NAME = "sweep"
DESCRIPTION = (
    "a grid of config variants (preset + overrides) over seeds: W+Prob k=1 and 5 and Standard k=1 on the "
    "100-place subset and on consecutive places, beside SAD and cosine nearest neighbour on the same pre-processed images, mean ± std over seeds"
)
KS = (1, 5)
SELECTIONS = ("subset", "consecutive")
#: The no-learning baselines on the images each variant's network sees (runtime.evaluation.evaluate_float).
BASELINE_TITLES = {"sad": "SAD", "cosine": "cosine"}
BASELINES = tuple(BASELINE_TITLES)
READOUT_SECTION = "assignment"  # config keys that change only the readout, never the trained network
DEFAULT_GRID = (
    Variant("paper", "paper"),
    Variant("paper+gamma0.1", "paper", {"assignment.gamma": 0.1}),
    Variant("dog", "dog"),
    Variant("dog+gamma0.1", "dog", {"assignment.gamma": 0.1}),
    Variant("dog-sigma1-2", "dog", {"preprocess.dog_sigma_centre": 1.0, "preprocess.dog_sigma_surround": 2.0}),
)


@dataclass(frozen=True)
class Network:
    """What one trained network is keyed by: its selection, seed and training config (readout keys reset)."""

    selection: str
    seed: int
    training: str  # JSON of the training config


def variant_config(settings: Settings, variant: Variant, seed: int) -> Config:
    """preset(variant.preset), then the settings' --set overrides, then the variant's own, then the seed."""
    return preset(variant.preset).replace(**{**settings.overrides, **variant.overrides, "seed": seed})


def training_config(cfg: Config) -> Config:
    """``cfg`` with the readout-only section reset to its default: the config a network is trained with."""
    return replace(cfg, assignment=AssignmentConfig())


def check_grid(settings: Settings, grid: tuple[Variant, ...]) -> None:
    """Every variant names a known preset and valid keys, and no name repeats: InvalidValueError otherwise."""
    names = [v.name for v in grid]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise InvalidValueError(f"--grid: variant name {repeated[0]!r} given more than once")
    for variant in grid:
        if variant.preset not in PRESETS:
            raise InvalidValueError(
                f"--grid {variant.name}: unknown preset {variant.preset!r}; choose from {', '.join(PRESETS)}"
            )
        try:
            variant_config(settings, variant, settings.seeds[0])
        except InvalidValueError as exc:
            raise InvalidValueError(f"--grid {variant.name}: {exc}") from None


def evaluate_selection(settings: Settings, selection: str, grid: tuple[Variant, ...]) -> dict[str, Any]:
    """Per variant: summary rows (mean ± std over seeds), per-seed rows and threshold candidates per step.

    One network is trained (or taken from the cache) per distinct training config and seed; every
    variant sharing it is read out from the same query counts with its own gamma.
    """
    device = resolve_device(settings.device)
    per_variant: dict[str, list[list[dict]]] = {v.name: [] for v in grid}
    candidates: dict[str, list[float]] = {v.name: [] for v in grid}
    network_of: dict[str, str] = {}
    n_places = 0
    for seed in settings.seeds:
        evaluated: dict[Network, tuple[Checkpoint, np.ndarray, Evaluation, str]] = {}
        for variant in grid:
            cfg = variant_config(settings, variant, seed)
            train_cfg = training_config(cfg)
            key = Network(selection, seed, json.dumps(train_cfg.to_dict(), sort_keys=True))
            if key not in evaluated:
                data = load(settings, selection, train_cfg)
                ckpt = trained_checkpoint(settings, data, train_cfg, selection)
                evaluation = evaluate_float(
                    ckpt,
                    data.traversal(settings.query),
                    data.place_ids,
                    settings.query,
                    SequenceOptions(ks=KS),
                    device=device,
                    reference_images={settings.reference: data.traversal(settings.reference)},
                )
                evaluated[key] = (ckpt, data.place_ids, evaluation, variant.name)
            ckpt, place_ids, evaluation, first = evaluated[key]
            network_of[variant.name] = first
            n_places = len(place_ids)
            readout = Readout(ckpt.calibration, cfg.assignment.gamma, SequenceOptions(ks=KS))  # the variant's gamma
            rows = readout.rows(evaluation.query_counts, ckpt.reference_place_ids, place_ids)
            baselines = [r for r in evaluation.rows if r["strategy"] in BASELINES]
            per_variant[variant.name].append(
                [dict(r, seed=seed) for r in [*(row.to_dict() for row in rows), *baselines]]
            )
            candidates[variant.name].append(evaluation.spike_stats.mean_candidates_per_step)
    return {
        "n_places": n_places,
        "variants": [
            {
                "variant": v.name,
                "network": network_of[v.name],
                "summary": summarise_rows(per_variant[v.name]),
                "per_seed": per_variant[v.name],
                "candidates_per_step": mean_std(candidates[v.name]).to_dict(),
            }
            for v in grid
        ],
    }


def run(settings: Settings) -> dict:
    started = time.perf_counter()
    grid = settings.grid or DEFAULT_GRID
    check_grid(settings, grid)
    return {
        "experiment": NAME,
        "grid": [asdict(v) for v in grid],
        **{selection: evaluate_selection(settings, selection, grid) for selection in SELECTIONS},
        "provenance": provenance(settings, started),
    }


def summary_row(block: dict, strategy: str, k: int) -> dict:
    return next(r for r in block["summary"] if r["strategy"] == strategy and r["k"] == k)


def selection_titles(results: dict) -> dict[str, str]:
    settings = results["provenance"]["settings"]
    start, _, count = settings["consecutive"].partition(":")
    span = f"places {start}-{int(start) + int(count or 1) - 1}"
    subset = "subset spread along the route" if settings["subset"] else f"subset not given: {span}"
    return {"subset": subset, "consecutive": f"consecutive {span}"}


def selection_table(block: dict) -> str:
    """One row per variant: W+Prob k=1 and 5 (accuracy, R@100P), Standard k=1, SAD and cosine k=1 and 5, in
    percent (a baseline column is left out of a block written before it was measured)."""
    baselines = [b for b in BASELINES if any(r["strategy"] == b for r in block["variants"][0]["summary"])]
    lines = [
        "| variant | network | W+Prob k=1 acc % | W+Prob k=1 R@100P % | W+Prob k=5 acc % | W+Prob k=5 R@100P % "
        "| Standard k=1 acc % | "
        + "".join(f"{BASELINE_TITLES[b]} k={k} acc / R@100P % | " for b in baselines for k in (1, 5))
        + "candidates / step | seeds |",
        "|---|---|" + "---:|" * (7 + 2 * len(baselines)),
    ]
    for entry in block["variants"]:
        wprob1, wprob5 = summary_row(entry, "wprob", 1), summary_row(entry, "wprob", 5)
        cells = [
            entry["variant"],
            entry["network"],
            pct(wprob1["accuracy"]),
            pct(wprob1["r_at_100p"]),
            pct(wprob5["accuracy"]),
            pct(wprob5["r_at_100p"]),
            pct(summary_row(entry, "standard", 1)["accuracy"]),
            *(baseline_cell(summary_row(entry, b, k)) for b in baselines for k in (1, 5)),
            f"{entry['candidates_per_step']['mean']:.1f}",
            str(wprob1["accuracy"]["n"]),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def baseline_cell(row: dict) -> str:
    """A seedless baseline's accuracy / R@100P in percent."""
    return f"{100 * row['accuracy']['mean']:.1f} / {100 * row['r_at_100p']['mean']:.1f}"


def plot(results: dict, path: Path) -> Path:
    """Per selection: W+Prob accuracy (k=1, k=5) per variant with error bars, SAD (dashed) and cosine (dotted)
    on the same images as ticks."""
    titles = selection_titles(results)
    fig = Figure(figsize=(4.2 * len(SELECTIONS), 4.2))
    axes = fig.subplots(1, len(SELECTIONS), sharey=True)
    for ax, selection in zip(np.atleast_1d(axes), SELECTIONS, strict=True):
        variants = results[selection]["variants"]
        x = np.arange(len(variants))
        for k, offset, colour in ((1, -0.12, "tab:blue"), (5, 0.12, "tab:orange")):
            rows = [summary_row(v, "wprob", k)["accuracy"] for v in variants]
            means = [100 * r["mean"] for r in rows]
            stds = [100 * r["std"] for r in rows]
            ax.errorbar(x + offset, means, yerr=stds, fmt="o", capsize=3, color=colour, label=f"W+Prob k={k}")
            for baseline, style in (("sad", "--"), ("cosine", ":")):
                if all(any(r["strategy"] == baseline for r in v["summary"]) for v in variants):
                    levels = [100 * summary_row(v, baseline, k)["accuracy"]["mean"] for v in variants]
                    label = f"{BASELINE_TITLES[baseline]} k={k}"
                    ax.hlines(levels, x - 0.35, x + 0.35, colors=colour, linestyles=style, linewidth=1, label=label)
        ax.set_xticks(x, [v["variant"] for v in variants], rotation=20, ha="right", fontsize=8)
        ax.set_title(titles[selection], fontsize=9)
        ax.set_ylim(0, 102)
        ax.grid(alpha=0.3, axis="y")
    first = np.atleast_1d(axes)[0]
    first.set_ylabel("accuracy % (mean ± std over seeds)")
    first.legend(fontsize=7, loc="lower left")
    return save_figure(fig, path)


def render(results: dict, out_dir: Path, stem: str = NAME) -> str:
    titles = selection_titles(results)
    grid = "; ".join(
        f"`{v['name']}` = preset `{v['preset']}`"
        + "".join(f", `{key}={json.dumps(value)}`" for key, value in v["overrides"].items())
        for v in results["grid"]
    )
    overrides = results["provenance"]["settings"]["overrides"]
    common = ", ".join(f"`{key}={json.dumps(value)}`" for key, value in overrides.items()) or "none"
    parts = [
        f"Grid: {grid}. Overrides applied to every variant (`--set`): {common}.\n",
        "`network` names the variant whose trained networks a row reads out: variants that differ only in "
        f"`{READOUT_SECTION}.*` keys share them (one training per seed). SAD is the no-learning baseline on "
        "the same pre-processed images the variant's network sees, read out through the W+Prob "
        "transformation; cosine is nearest neighbour by cosine similarity on the same images (the template "
        "ceiling: margin between best and second-best as confidence, k frames summed along the diagonal). "
        "Neither has a seed, so each is shown as accuracy / R@100P.\n",
    ]
    for selection in SELECTIONS:
        block = results[selection]
        parts.append(
            f"## {titles[selection]} ({block['n_places']} places)\n\n"
            f"Accuracy and R@100P in %, mean ± std over seeds.\n\n{selection_table(block)}\n"
        )
    plot(results, out_dir / f"{stem}.png")
    parts.append(f"![accuracy per variant]({stem}.png)\n")
    return "\n".join(parts)
