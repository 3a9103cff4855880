"""Table IV: the operational envelope of sequence aggregation (k=5, product rule), windows from the query stream only."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from vprsnn_export.device import resolve_device
from vprsnn_export.readout.aggregation import aggregate, estimate_velocity
from vprsnn_export.readout.assignment import strategy_scores
from vprsnn_export.runtime.evaluation import ReadoutOptions, decision_metrics, evaluate_float

from .common import Settings, consecutive_networks, provenance, rows_table, summarise_rows

NAME = "envelope"
DESCRIPTION = (
    "W+Prob k=5 product rule under velocity mismatch, dropped frames, reversal and route deviations, "
    "with and without per-window velocity estimation (100 consecutive places)"
)
K = 5
VELOCITY_GRID = tuple(np.round(np.arange(-2.0, 2.0001, 0.05), 2))


def conditions(n: int, rng: np.random.Generator) -> list[tuple[str, np.ndarray, np.ndarray, float]]:
    """(name, query order, frame positions the robot knows, assumed velocity) for each condition.

    Frame positions are the robot's own clock/odometry: the stream index, or the
    original frame index when frames are dropped. Ground truth is never used.
    """
    order = np.arange(n)
    rows = [("baseline (1.0x)", order, order.astype(float), 1.0)]
    for error in (0.1, -0.1, 0.2, -0.2, 0.5, -0.5):
        rows.append((f"velocity mismatch ({error:+.0%})", order, order.astype(float), 1.0 + error))
    rows.append(("reverse traversal", order[::-1], order.astype(float), 1.0))
    for fraction in (0.1, 0.5):
        kept = np.sort(rng.choice(n, size=int(round(n * (1 - fraction))), replace=False))
        rows.append((f"{fraction:.0%} dropped frames", kept, kept.astype(float), 1.0))
    blocks = np.array_split(order, 5)
    shuffled = np.concatenate([blocks[i] for i in rng.permutation(5)])
    rows.append(("route deviations (5 segments reordered)", shuffled, order.astype(float), 1.0))
    return rows


def run(settings: Settings) -> dict:
    started = time.perf_counter()
    per_seed = []
    for seed, cfg, data, ckpt in consecutive_networks(settings):
        counts = evaluate_float(
            ckpt,
            data.traversal(settings.query),
            data.place_ids,
            settings.query,
            ReadoutOptions(gamma=cfg.assignment.gamma),
            device=resolve_device(settings.device),
        )
        wprob = strategy_scores(
            ckpt.calibration.astype(float), counts.query_counts.astype(float), "wprob", cfg.assignment.gamma
        )
        rows = []
        rng = np.random.default_rng(seed)
        for name, order, positions, velocity in conditions(len(data.place_ids), rng):
            given = aggregate(wprob[order], K, velocity, rule="product", frame_positions=positions)
            _, estimated = estimate_velocity(
                wprob[order], K, np.asarray(VELOCITY_GRID), rule="product", frame_positions=positions
            )
            for mode, dist in (("given velocity", given), ("estimated velocity", estimated)):
                metrics = decision_metrics(dist, "wprob", ckpt.reference_place_ids, data.place_ids[order], 0)
                rows.append({"condition": name, "velocity": mode, "strategy": "wprob", "k": K, **metrics})
        per_seed.append(rows)
    return {
        "experiment": NAME,
        "summary": summarise_rows(per_seed, ("condition", "velocity")),
        "per_seed": per_seed,
        "velocity_grid": list(VELOCITY_GRID),
        "provenance": provenance(settings, started),
    }


def render(results: dict, out_dir: Path, stem: str = NAME) -> str:
    return (
        rows_table(results["summary"], ("condition", "velocity"))
        + f"\n\nEstimated velocity: searched per window over {results['velocity_grid'][0]} .. "
        f"{results['velocity_grid'][-1]} places/frame in steps of 0.05 (keeps the best-scoring window).\n"
    )
