"""Table I: the full model vs each core mechanism switched off (W+Prob, 100-place subset)."""

from __future__ import annotations

import time
from pathlib import Path

from .common import Settings, load, provenance, rows_table, summarise_rows, trained_checkpoint
from .query import evaluate_query

NAME = "ablation"
DESCRIPTION = "full model vs WTA off, homeostasis off, patch normalisation off, weight normalisation off"
VARIANTS = {
    "full": {},
    "WTA off": {"network.wta": False},
    "homeostasis off": {"homeostasis.enabled": False},
    "patch normalisation off": {"preprocess.patch_norm": False},
    "weight normalisation off": {"stdp.weight_norm": False},
}


def run(settings: Settings) -> dict:
    started = time.perf_counter()
    per_seed = []
    for seed in settings.seeds:
        rows = []
        for variant, change in VARIANTS.items():
            cfg = settings.config(seed, **change)
            data = load(settings, "subset", cfg)
            ckpt = trained_checkpoint(settings, data, cfg, "subset")
            result = evaluate_query(settings, ckpt, data, cfg)
            rows += [
                dict(r, variant=variant, seed=seed, **result.spike_stats.to_dict())
                for r in result.rows
                if r["strategy"] == "wprob"
            ]
        per_seed.append(rows)
    return {
        "experiment": NAME,
        "summary": summarise_rows(per_seed, ("variant", "strategy", "k")),
        "per_seed": per_seed,
        "provenance": provenance(settings, started),
    }


def render(results: dict, out_dir: Path, stem: str = NAME) -> str:
    return rows_table(results["summary"], ("variant", "strategy", "k")) + "\n"
