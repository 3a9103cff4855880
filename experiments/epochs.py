"""Accuracy and R@100P against training epochs: how the default epoch count was chosen."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from vprsnn_export.device import resolve_device
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.evaluation import calibrate_and_evaluate
from vprsnn_export.stats import mean_std
from vprsnn_export.trainer.train import Presentation, train_network

from .common import Settings, load, provenance
from .plots import line_plot

NAME = "epochs"
DESCRIPTION = "accuracy / R@100P (W+Prob, k=1 and k=5) vs training epochs on the 100-place subset"
FULL_EPOCHS = (1, 2, 5, 10, 20, 30, 40, 60, 80, 100, 120)
QUICK_EPOCHS = (1, 2, 3)


def run(settings: Settings) -> dict:
    started = time.perf_counter()
    marks = QUICK_EPOCHS if settings.quick else FULL_EPOCHS
    device = resolve_device(settings.device)
    per_seed: list[dict[str, Any]] = []
    for seed in settings.seeds:
        cfg = settings.config(seed, **{"train.epochs": max(marks)})
        data = load(settings, "subset", cfg)
        options = SequenceOptions(ks=(1, 5))
        reference = {settings.reference: data.traversal(settings.reference)}

        def on_epoch(epoch, weights, theta, cfg=cfg, data=data, options=options, reference=reference):
            if epoch not in marks:
                return None
            network = FloatNetwork(weights, theta, cfg)
            rows = calibrate_and_evaluate(
                network,
                reference,
                data.place_ids,
                data.traversal(settings.query),
                data.place_ids,
                settings.query,
                options,
            )
            return {"rows": [row.to_dict() for row in rows]}

        images = data.traversal(settings.reference)
        presentations = [Presentation(settings.reference, int(p)) for p in data.place_ids]
        trained = train_network(
            images, presentations, cfg, device=device, progress=settings.progress, on_epoch=on_epoch
        )
        per_seed.append({"seed": seed, "history": trained.history})
    curve = []
    for mark in marks:
        entry: dict[str, Any] = {"epoch": mark}
        for strategy, k in (("standard", 1), ("wprob", 1), ("wprob", 5)):
            for metric in ("accuracy", "r_at_100p"):
                values = [
                    row[metric]
                    for seed in per_seed
                    for row in seed["history"][mark - 1]["rows"]
                    if row["strategy"] == strategy and row["k"] == k
                ]
                entry[f"{strategy}_k{k}_{metric}"] = mean_std(values).to_dict()
        entry["seconds_per_epoch"] = mean_std(s["history"][mark - 1]["seconds"] for s in per_seed).to_dict()
        curve.append(entry)
    return {"experiment": NAME, "curve": curve, "per_seed": per_seed, "provenance": provenance(settings, started)}


def render(results: dict, out_dir: Path, stem: str = NAME) -> str:
    curve = results["curve"]
    epochs = [c["epoch"] for c in curve]
    series = {
        label: ([100 * c[key]["mean"] for c in curve], [100 * c[key]["std"] for c in curve])
        for label, key in (
            ("W+Prob k=1 accuracy", "wprob_k1_accuracy"),
            ("W+Prob k=1 R@100P", "wprob_k1_r_at_100p"),
            ("W+Prob k=5 accuracy", "wprob_k5_accuracy"),
            ("W+Prob k=5 R@100P", "wprob_k5_r_at_100p"),
            ("Standard k=1 accuracy", "standard_k1_accuracy"),
        )
    }
    line_plot(
        out_dir / f"{stem}.png",
        epochs,
        series,
        xlabel="training epochs",
        ylabel="%",
        log_x=True,
        title="Accuracy and R@100P vs epochs (summer -> winter, 100 places)",
    )
    lines = [
        "| epochs | W+Prob k=1 acc % | W+Prob k=1 R@100P % | W+Prob k=5 acc % | W+Prob k=5 R@100P % | Standard k=1 acc % | s/epoch |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for c in curve:
        cells = [
            f"{100 * c[k]['mean']:.1f} ± {100 * c[k]['std']:.1f}"
            for k in (
                "wprob_k1_accuracy",
                "wprob_k1_r_at_100p",
                "wprob_k5_accuracy",
                "wprob_k5_r_at_100p",
                "standard_k1_accuracy",
            )
        ]
        lines.append(f"| {c['epoch']} | " + " | ".join(cells) + f" | {c['seconds_per_epoch']['mean']:.2f} |")
    return "\n".join(lines) + f"\n\n![accuracy vs epochs]({stem}.png)\n"
