"""Table VI: state isolation on vs off on the *same* trained networks, every strategy, several seeds."""

from __future__ import annotations

import time
from pathlib import Path

from vprsnn_export.device import resolve_device
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.evaluation import evaluate_float

from .common import Settings, consecutive_networks, provenance, rows_table, summarise_rows

NAME = "state_isolation"
DESCRIPTION = (
    "query-state isolation vs spillover on the same trained networks (calibration as deployed, "
    "isolated), all strategies at k=1 and W+Prob k=5, 100 consecutive places"
)


def run(settings: Settings) -> dict:
    started = time.perf_counter()
    per_seed = []
    for seed, _cfg, data, ckpt in consecutive_networks(settings):
        rows = []
        for state, isolation in (("isolated", True), ("spillover", False)):
            result = evaluate_float(
                ckpt,
                data.traversal(settings.query),
                data.place_ids,
                settings.query,
                SequenceOptions(ks=(1, 5)),
                device=resolve_device(settings.device),
                state_isolation=isolation,
            )
            rows += [dict(r, state=state, seed=seed) for r in result.rows]
        per_seed.append(rows)
    return {
        "experiment": NAME,
        "summary": summarise_rows(per_seed, ("strategy", "k", "state")),
        "per_seed": per_seed,
        "provenance": provenance(settings, started),
    }


def render(results: dict, out_dir: Path, stem: str = NAME) -> str:
    return rows_table(results["summary"], ("strategy", "k", "state")) + "\n"
