"""Table III and II: Standard / Weighted / W+Prob over independently trained networks, with the SAD baseline."""

from __future__ import annotations

import time
from pathlib import Path

from vprsnn_export.device import resolve_device
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.evaluation import evaluate_float
from vprsnn_export.stats import mean_std

from .common import Settings, load, provenance, rows_table, summarise_rows, trained_checkpoint

NAME = "assignment"
DESCRIPTION = (
    "assignment strategies on the 100-place subset (k=1) and W+Prob k=1,3,5 on 100 consecutive places, "
    "beside the no-learning SAD baseline, mean ± std over seeds"
)
KS = (1, 3, 5)


def evaluate_selection(settings: Settings, selection: str, ks: tuple[int, ...]) -> dict:
    per_seed, stats = [], []
    for seed in settings.seeds:
        cfg = settings.config(seed)
        data = load(settings, selection, cfg)
        ckpt = trained_checkpoint(settings, data, cfg, selection)
        result = evaluate_float(
            ckpt,
            data.traversal(settings.query),
            data.place_ids,
            settings.query,
            SequenceOptions(ks=ks),
            device=resolve_device(settings.device),
            reference_images={settings.reference: data.traversal(settings.reference)},
        )
        per_seed.append([dict(r, seed=seed) for r in result.rows])
        stats.append(result.spike_stats.to_dict())
    return {
        "summary": summarise_rows(per_seed),
        "per_seed": per_seed,
        "spike_stats": {key: mean_std(s[key] for s in stats).to_dict() for key in stats[0]},
        "n_places": int(len(data.place_ids)),
    }


def run(settings: Settings) -> dict:
    started = time.perf_counter()
    return {
        "experiment": NAME,
        "subset": evaluate_selection(settings, "subset", (1,)),
        "consecutive": evaluate_selection(settings, "consecutive", KS),
        "provenance": provenance(settings, started),
    }


def render(results: dict, out_dir: Path, stem: str = NAME) -> str:
    parts = []
    for key, title in (
        ("subset", "100-place subset (spread along the route), k = 1"),
        (
            "consecutive",
            f"consecutive places ({results['provenance']['settings']['consecutive']}), W+Prob aggregated over k frames",
        ),
    ):
        block = results[key]
        stats = block["spike_stats"]
        parts.append(
            f"## {title}\n\n{rows_table(block['summary'])}\n\n"
            f"Threshold candidates per step: {stats['mean_candidates_per_step']['mean']:.1f} on average; "
            f"steps with more than one candidate: {100 * stats['multi_candidate_step_fraction']['mean']:.1f} %; "
            f"spikes per query: {stats['mean_spikes_per_query']['mean']:.1f}.\n"
        )
    parts.append(
        "Strategy `sad` is the no-learning baseline: sum of absolute differences between the same "
        "patch-normalised images, read out through the W+Prob transformation (docs/readout.md).\n"
    )
    return "\n".join(parts)
