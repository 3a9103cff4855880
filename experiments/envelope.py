"""Table IV: the operational envelope of sequence aggregation (k=5, product rule), windows from the query stream only.

Every condition is read out with four velocity sources -- the given velocity,
the per-window search, the velocity tracked over the query stream and the
velocity smoothed with a fixed lag -- for the network's W+Prob and for the
no-learning SAD baseline on the same windows.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from vprsnn_export.data.truth import EXACT
from vprsnn_export.device import resolve_device
from vprsnn_export.readout.aggregation import aggregate, estimate_velocity, smooth_velocity, track_velocity
from vprsnn_export.readout.baseline import sad_distances, sad_distribution
from vprsnn_export.readout.scoring import decision_metrics
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.readout.strategies import strategy_scores
from vprsnn_export.runtime.evaluation import evaluate_float

from .common import Settings, consecutive_networks, mean_std, pct, provenance, rows_table, summarise_rows

NAME = "envelope"
DESCRIPTION = (
    "W+Prob and SAD, k=5 product rule, under velocity mismatch, dropped frames, reversal and route deviations, "
    "with the given velocity, the per-window search, the tracked and the smoothed velocity (100 consecutive places)"
)
K = 5
VELOCITY_GRID = tuple(float(v) for v in np.round(np.arange(-2.0, 2.0001, 0.05), 2))
SPAN = 10  # windows whose scores the tracker sums
LENGTH = 2 * K  # frames per trajectory the tracker scores
#: recent frames whose mean the tracker divides out: W+Prob has "hub" places that runs of consecutive
#: frames all vote for; the SAD distribution has none, and dividing its flat rows only adds noise
MEMORY = {"wprob": 50, "sad": 0}
SMOOTH_LAG = 2 * K - 1  # frames each smoothed decision waits for: the windows after it also set its velocity
SMOOTH_LENGTH = 3 * K  # frames per trajectory the smoother scores (through whole places)
WARMUP = 30  # queries at the start of the stream left out of the "after warm-up" accuracy (at most half)
SOURCES = ("given", "per-window search", "tracked", "smoothed")
METHODS = ("wprob", "sad")
KEYS = ("condition", "method", "velocity")


def conditions(n: int, rng: np.random.Generator) -> list[tuple[str, np.ndarray, np.ndarray, float]]:
    """(name, query order, frame positions the robot knows, given velocity) for each condition.

    Frame positions are the robot's own clock/odometry: the stream index, or the
    original frame index when frames are dropped. Ground truth is never used.
    The given velocity is what the robot is told; the estimators ignore it.
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
    doubled = order[::2]
    rows.append(("double speed, unknown (every 2nd place)", doubled, np.arange(doubled.size, dtype=float), 1.0))
    return rows


def envelope_rows(
    distributions: dict[str, np.ndarray],
    reference_place_ids: np.ndarray,
    query_place_ids: np.ndarray,
    rng: np.random.Generator,
) -> list[dict]:
    """Rows {condition, method, velocity, k, metrics..., velocity_median} for one network.

    ``distributions[method]`` is the (queries, places) distribution of each
    method (W+Prob, SAD) in stream order of the unchanged traversal.
    """
    rows = []
    grid = np.asarray(VELOCITY_GRID)
    for name, order, positions, velocity in conditions(len(query_place_ids), rng):
        for method, dist in distributions.items():
            stream = dist[order]
            per_source = {
                "given": (np.full(len(order), velocity), aggregate(stream, K, velocity, "product", positions)),
                "per-window search": estimate_velocity(stream, K, grid, "product", positions),
                "tracked": track_velocity(
                    stream, K, grid, SPAN, "product", positions, length=LENGTH, memory=MEMORY[method]
                ),
                "smoothed": smooth_velocity(
                    stream,
                    K,
                    grid,
                    SPAN,
                    "product",
                    positions,
                    lag=SMOOTH_LAG,
                    length=SMOOTH_LENGTH,
                    memory=MEMORY[method],
                ),
            }
            for source, (v, agg) in per_source.items():
                truth = query_place_ids[order]
                metrics = decision_metrics(agg, "wprob", reference_place_ids, truth, EXACT)
                skip = min(WARMUP, len(order) // 2)
                settled = decision_metrics(agg[skip:], "wprob", reference_place_ids, truth[skip:], EXACT)
                rows.append(
                    {
                        "condition": name,
                        "method": method,
                        "velocity": source,
                        "k": K,
                        **metrics,
                        "accuracy_after_warmup": settled["accuracy"],
                        "velocity_median": float(np.median(v[K - 1 :])),
                    }
                )
    return rows


def network_distributions(settings: Settings, cfg, data, ckpt) -> dict[str, np.ndarray]:
    """W+Prob of the network and the SAD baseline distribution for the query traversal."""
    query = data.traversal(settings.query)
    counts = evaluate_float(
        ckpt,
        query,
        data.place_ids,
        settings.query,
        SequenceOptions(),
        device=resolve_device(settings.device),
    )
    wprob = strategy_scores(
        ckpt.calibration.astype(float), counts.query_counts.astype(float), "wprob", cfg.assignment.gamma
    )
    reference = np.mean([data.traversal(name) for name in ckpt.reference_traversals], axis=0)
    return {"wprob": wprob, "sad": sad_distribution(sad_distances(reference, query))}


def run(settings: Settings) -> dict:
    started = time.perf_counter()
    per_seed = []
    for seed, cfg, data, ckpt in consecutive_networks(settings):
        distributions = network_distributions(settings, cfg, data, ckpt)
        rows = envelope_rows(distributions, ckpt.reference_place_ids, data.place_ids, np.random.default_rng(seed))
        per_seed.append([dict(r, seed=seed) for r in rows])
    return {
        "experiment": NAME,
        "summary": summarise_rows(per_seed, KEYS),
        "per_seed": per_seed,
        **estimator_settings(),
        "provenance": provenance(settings, started),
    }


def estimator_settings() -> dict:
    return {
        "k": K,
        "velocity_grid": list(VELOCITY_GRID),
        "track_span": SPAN,
        "track_length": LENGTH,
        "track_memory": MEMORY,
        "smooth_lag": SMOOTH_LAG,
        "smooth_length": SMOOTH_LENGTH,
        "warmup": WARMUP,
    }


def compact_table(summary: list[dict]) -> str:
    """Conditions down, method x velocity source across; each cell "accuracy / R@100P" (mean ± std, %)."""
    columns = [(m, s) for m in METHODS for s in SOURCES]
    cells = {(r["condition"], r["method"], r["velocity"]): r for r in summary}
    names = list(dict.fromkeys(r["condition"] for r in summary))
    labels = [f"{'W+Prob' if m == 'wprob' else 'SAD'} {s}" for m, s in columns]
    lines = ["| condition | " + " | ".join(labels) + " |", "|---|" + "---|" * len(columns)]
    for name in names:
        row = [cells[(name, m, s)] for m, s in columns]
        lines.append(f"| {name} | " + " | ".join(f"{pct(r['accuracy'])} / {pct(r['r_at_100p'])}" for r in row) + " |")
    return "\n".join(lines)


def explanation(results: dict) -> str:
    grid = results["velocity_grid"]
    return (
        f"k = {results['k']}, product rule. Each cell: accuracy / R@100P in % (mean ± std over seeds).\n\n"
        "* **given**: the velocity the robot is told (1.0 place/frame, or wrong by the stated error). "
        "The estimators ignore it, so their velocity-mismatch rows equal the baseline row.\n"
        f"* **per-window search**: each window keeps its best-scoring velocity on the grid {grid[0]} .. {grid[-1]} "
        "(step 0.05) on its own (`estimate_velocity`).\n"
        "* **tracked** (`track_velocity`, causal, query stream only): each frame is divided by the mean of the "
        f"most recent frames ({results['track_memory']['wprob']} for W+Prob, which has places that runs of "
        f"consecutive frames all vote for; {results['track_memory']['sad']}, i.e. not at all, for SAD), "
        f"trajectories of {results['track_length']} frames are scored on the same grid, and the scores of the "
        f"{results['track_span']} most recent windows are summed before the velocity is chosen; the decision "
        "aggregates the unchanged distributions over k frames at that velocity.\n"
        f"* **smoothed** (`smooth_velocity`, fixed lag): each decision is given {results['smooth_lag']} frames "
        "late, and the velocity of its window sums the scores of the same recent windows and of the "
        f"{results['smooth_lag']} windows after it (the contrast background also takes those frames); "
        f"trajectories of {results['smooth_length']} frames go through whole places (each frame shifted by a "
        "rounded number of places, as in SeqSLAM) and the centre of the tied best velocities is kept. The "
        "decision still aggregates the k frames up to the query, as with a given velocity.\n"
        "* **SAD**: the no-learning baseline (sum of absolute differences to the reference images), aggregated on "
        "the same windows with the same velocity sources.\n"
        "* Windows come from the query stream and the robot's frame positions only; no ground truth. "
        "Dropped frames keep their original frame index as position; reversed and reordered streams keep the "
        "stream index; at double speed the robot's clock still says 1 frame per step.\n"
    )


def warmup_table(per_seed: list[list[dict]], warmup: int) -> str:
    """Accuracy on the whole stream and after the first ``warmup`` queries, per method and velocity source."""
    lines = [
        f"| condition | method | velocity | accuracy % | accuracy after the first {warmup} queries % |",
        "|---|---|---|---|---|",
    ]
    groups: dict[tuple, list[dict]] = {}
    for rows in per_seed:
        for row in rows:
            groups.setdefault((row["condition"], row["method"], row["velocity"]), []).append(row)
    for (condition, method, source), rows in groups.items():
        if condition.startswith(("baseline", "reverse")):
            whole = mean_std(r["accuracy"] for r in rows).to_dict()
            after = mean_std(r["accuracy_after_warmup"] for r in rows).to_dict()
            lines.append(f"| {condition} | {method} | {source} | {pct(whole)} | {pct(after)} |")
    return "\n".join(lines)


def render(results: dict, out_dir: Path, stem: str = NAME) -> str:
    return (
        compact_table(results["summary"])
        + "\n\n"
        + explanation(results)
        + "\n## Warm-up: the first queries of the stream\n\n"
        + warmup_table(results["per_seed"], results["warmup"])
        + "\n"
        + "\n## Every metric\n\n"
        + rows_table(results["summary"], KEYS)
        + "\n"
    )
