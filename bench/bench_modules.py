"""Modules side by side: batched training against the plain loop over modules, and ensemble inference speed.

    OMP_NUM_THREADS=1 python bench/bench_modules.py [--data DIR] [--modules 4] [--module-size 100] [--epochs 2]
                                                  [--route-modules 24] [--queries 40]

Training: --modules modules of --module-size places (summer images of --data, or the synthetic
route when it is absent), --epochs epochs of the default configuration, trained (a) one after
another by ``train_network`` on each region (the plain loop), (b) side by side by
``train_modules`` on one thread and (c) on two threads; every module's weights and thresholds
are checked to be the same bit for bit in (a), (b) and (c). Inference: --queries winter
presentations through an ensemble of --route-modules modules of ``network.n_neurons`` neurons
(random column-normalised weights, thresholds 2.0) by ``float_run`` on 1 and 2 threads, the
counts checked equal. Times are wall-clock seconds of one run each (the machine may be shared:
the load average is printed).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import torch

from vprsnn_export.config import Config
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.network.dynamics_kernel import float_run
from vprsnn_export.trainer.batched import module_training_rows, train_modules
from vprsnn_export.trainer.train import Presentation, train_network

NORDLAND = Path(__file__).resolve().parents[1].parent.parent / "shared/data/nordland_64x32_summer_winter"


def images_of(data: Path, count: int, traversal: str, cfg: Config) -> tuple[np.ndarray, np.ndarray]:
    source = str(data) if data.exists() else f"synthetic:{count}"
    dataset = load_dataset(
        source, [traversal], cfg.preprocess, places=None if "synthetic" in source else f"0:{count}", progress=False
    )
    return dataset.traversal(traversal)[:count], dataset.place_ids[:count]


def timed(run):
    started = time.perf_counter()
    result = run()
    return time.perf_counter() - started, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=NORDLAND)
    parser.add_argument("--modules", type=int, default=4)
    parser.add_argument("--module-size", type=int, default=100)
    parser.add_argument("--epochs", type=int, default=2)
    parser.add_argument("--route-modules", type=int, default=24)
    parser.add_argument("--queries", type=int, default=40)
    args = parser.parse_args()
    torch.set_num_threads(1)
    cfg = Config().replace(**{"train.epochs": args.epochs, "train.module_size": args.module_size})
    n_places = args.modules * args.module_size
    images, place_ids = images_of(args.data, n_places, "summer", cfg)
    presentations = [Presentation("summer", int(p)) for p in place_ids]
    rows = module_training_rows(len(images), args.module_size, 1)
    cpu = torch.device("cpu")
    train_modules(
        images[:4], presentations[:4], [np.arange(4)], cfg.replace(**{"train.epochs": 1}), device=cpu, progress=False
    )
    loop_s, alone = timed(
        lambda: [train_network(images[r], [presentations[i] for i in r], cfg, device=cpu, progress=False) for r in rows]
    )
    one_s, together = timed(
        lambda: train_modules(images, presentations, rows, cfg, device=cpu, progress=False, threads=1)
    )
    two_s, together2 = timed(
        lambda: train_modules(images, presentations, rows, cfg, device=cpu, progress=False, threads=2)
    )
    n = cfg.network.n_neurons
    same = all(
        torch.equal(t.weights[:, m * n : (m + 1) * n], a.weights)
        and torch.equal(t.thresholds[m * n : (m + 1) * n], a.thresholds)
        for t in (together, together2)
        for m, a in enumerate(alone)
    )
    print(f"load average before inference: {os.getloadavg()}")
    print(
        f"\ntraining: {args.modules} modules x {args.module_size} places, {args.epochs} epochs, default config; same weights: {same}"
    )
    print("| trainer | threads | seconds | vs plain loop |")
    print("|---|---|---|---|")
    for name, threads, seconds in (
        ("plain loop (train_network per region)", 1, loop_s),
        ("train_modules", 1, one_s),
        ("train_modules", 2, two_s),
    ):
        print(f"| {name} | {threads} | {seconds:.2f} | {loop_s / seconds:.2f}x |")

    winter, winter_ids = images_of(args.data, args.queries, "winter", cfg)
    spikes = query_spikes(winter, winter_ids, "winter", cfg)
    gen = np.random.default_rng(0)
    weights = gen.random((cfg.network.n_inputs, args.route_modules * n)).astype(np.float32)
    weights /= np.linalg.norm(weights, axis=0, keepdims=True)
    theta = np.full(args.route_modules * n, 2.0, dtype=np.float32)
    float_run(spikes[:1], weights, theta, beta=cfg.network.beta, group=n, threads=1)
    float_run(spikes[:2], weights, theta, beta=cfg.network.beta, group=n, threads=2)
    results = {}
    for threads in (1, 2):
        seconds, run = timed(lambda: float_run(spikes, weights, theta, beta=cfg.network.beta, group=n, threads=threads))
        results[threads] = (seconds, run.counts)
    same = torch.equal(results[1][1], results[2][1])
    print(
        f"\ninference: {len(spikes)} queries (T={cfg.encoder.timesteps}) through {args.route_modules} modules = {args.route_modules * n} neurons (float_run); same counts: {same}"
    )
    print("| threads | seconds | queries/s |")
    print("|---|---|---|")
    for threads, (seconds, _) in results.items():
        print(f"| {threads} | {seconds:.2f} | {len(spikes) / seconds:.1f} |")
    print(f"\nload average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
