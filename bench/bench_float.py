"""Float path benchmark: training time per epoch and batched inference vs a plain per-step loop.

    python bench/bench_float.py [--data PATH] [--queries 100] [--repeats 3]

Prints one table. The reference loop presents one query at a time and computes
each step's current as its own vector-matrix product (the textbook loop); the
batched path is `vprsnn_export.network.dynamics.run_network` (one current matmul for all
queries and steps, then a recurrence over t vectorised over queries and neurons).
Both run here, side by side, on the same spikes, and must give the same counts.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from vprsnn_export.config import Config
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.network.dynamics import run_network, wta_step
from vprsnn_export.trainer.train import Presentation, train_network

NORDLAND = Path("../shared/data/nordland_64x32_summer_winter")


def reference_loop(spikes: torch.Tensor, weights: torch.Tensor, theta: torch.Tensor, beta: float) -> torch.Tensor:
    """One query at a time, one step at a time: I = s[t] @ W, then the WTA step."""
    counts = torch.zeros((spikes.shape[0], weights.shape[1]), dtype=torch.int64)
    for n in range(spikes.shape[0]):
        voltage = torch.zeros((1, weights.shape[1]))
        for t in range(spikes.shape[1]):
            current = spikes[n, t].to(torch.float32)[None, :] @ weights
            voltage, fired, _ = wta_step(voltage, current, theta, beta, True)
            counts[n] += fired[0]
    return counts


def best_of(repeats: int, fn) -> tuple[float, object]:
    best, result = float("inf"), None
    for _ in range(repeats):
        started = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - started)
    return best, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(NORDLAND / "places.csv"))
    parser.add_argument("--queries", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--reference-queries", type=int, default=10, help="queries timed in the slow reference loop")
    args = parser.parse_args()
    data = args.data if Path(args.data).exists() else "synthetic:100"
    cfg = Config()
    dataset = load_dataset(
        data,
        ["summer", "winter"],
        cfg.preprocess,
        places=f"0:{args.queries}" if data.startswith("synthetic") else f"1000:{args.queries}",
    )
    images = dataset.traversal("summer")
    presentations = [Presentation("summer", int(p)) for p in dataset.place_ids]
    rows = []
    for timesteps in (150, 300):
        run_cfg = cfg.replace(**{"encoder.timesteps": timesteps, "train.epochs": 1})
        train_s, trained = best_of(
            args.repeats,
            lambda: train_network(images, presentations, run_cfg, device=torch.device("cpu"), progress=False),
        )
        spikes = query_spikes(dataset.traversal("winter"), dataset.place_ids, "winter", run_cfg)
        w, th = trained.weights, trained.thresholds
        fast_s, fast = best_of(args.repeats, lambda: run_network(spikes, w, th, beta=cfg.network.beta).counts)
        m = args.reference_queries
        ref_s, ref = best_of(1, lambda: reference_loop(spikes[:m], w, th, cfg.network.beta))
        assert torch.equal(ref, fast[:m]), "batched and reference loops disagree"
        fast_qps = len(spikes) / fast_s
        ref_qps = m / ref_s
        rows.append((timesteps, len(images), train_s, fast_qps, ref_qps, fast_qps / ref_qps))
    print(f"data: {data}; torch {torch.__version__}, {torch.get_num_threads()} threads, CPU")
    print(f"{'T':>4} {'train s/epoch':>14} {'batched q/s':>12} {'ms/query':>9} {'ref loop q/s':>13} {'ratio':>7}")
    for timesteps, _n, train_s, fast_qps, ref_qps, ratio in rows:
        print(
            f"{timesteps:>4} {train_s:>14.2f} {fast_qps:>12.1f} {1000 / fast_qps:>9.2f} {ref_qps:>13.1f} {ratio:>6.1f}x"
        )
    print(f"(training: {len(images)} images, batch {cfg.train.batch_size}; inference: {args.queries} queries batched)")


if __name__ == "__main__":
    main()
