"""Ray sharding: the cost of running an ensemble's modules as tasks, against the same tasks run here.

    OMP_NUM_THREADS=1 python bench/bench_cluster.py [--modules 8] [--module-size 10] [--epochs 1]
                                                  [--timesteps 50] [--workers 1,2]

Trains --modules modules of --module-size synthetic places (random 784-pixel images; the cost of
a task does not depend on the pixels) by ``train_modules_on_cluster``, one task per module:
(a) in this process (no cluster: the plain loop over tasks), then (b) on a local Ray runtime of
N worker processes for each N in --workers: the runtime's start, a first map (cold: each worker
imports the package and loads the compiled kernels) and a second map (warm). Each map is checked
to give the weights of (a) bit for bit. The scheduling overhead per module is

    overhead = (map wall time x N - sum of the tasks' own run times) / modules

i.e. what a module costs beyond its own training (task submission, argument and result
transfer, waiting), with the N workers' time added up. Times are wall-clock seconds of one run
each (the machine may be shared: the load average is printed).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch

from vprsnn_export.cluster import Cluster, TaskTiming
from vprsnn_export.config import Config
from vprsnn_export.trainer.batched import module_training_rows
from vprsnn_export.trainer.sharded import train_modules_on_cluster
from vprsnn_export.trainer.train import Presentation


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--modules", type=int, default=8)
    parser.add_argument("--module-size", type=int, default=10)
    parser.add_argument("--epochs", type=int, default=1)
    parser.add_argument("--timesteps", type=int, default=50)
    parser.add_argument("--workers", default="1,2", help="local Ray worker counts, e.g. 1,2")
    args = parser.parse_args()
    import ray  # the cluster extra (also in the test extra)

    torch.set_num_threads(1)
    cfg = Config().replace(
        **{"train.epochs": args.epochs, "train.module_size": args.module_size, "encoder.timesteps": args.timesteps}
    )
    n_places = args.modules * args.module_size
    images = np.random.default_rng(0).random((n_places, cfg.network.n_inputs)).astype(np.float32)
    presentations = [Presentation("summer", p) for p in range(n_places)]
    rows = module_training_rows(n_places, args.module_size, 1)

    def shard(cluster: Cluster | None) -> tuple[TaskTiming, torch.Tensor]:
        timing: list[TaskTiming] = []
        trained = train_modules_on_cluster(images, presentations, rows, cfg, cluster, timing=timing)
        return timing[0], trained.weights

    shard(None)  # compile or load the kernels here first
    here, expected = shard(None)
    table = [("here (no cluster)", 1, "-", here, True)]
    for workers in (int(w) for w in args.workers.split(",")):
        started = time.perf_counter()
        ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False, configure_logging=False)
        start_s = time.perf_counter() - started
        cluster = Cluster("local", workers, 1)
        for label in ("cold", "warm"):
            timing, weights = shard(cluster)
            table.append(
                (f"ray local:{workers} ({label})", workers, f"{start_s:.1f}", timing, torch.equal(weights, expected))
            )
        ray.shutdown()
    print(
        f"{args.modules} modules x {args.module_size} places, T={args.timesteps}, {args.epochs} epoch(s), "
        f"n={cfg.network.n_neurons}; load average {os.getloadavg()[0]:.2f}"
    )
    print(
        f"{'run':<24} {'workers':>7} {'start s':>8} {'map s':>7} {'tasks s':>8} {'overhead/module s':>18} {'same':>5}"
    )
    for label, workers, start, timing, same in table:
        overhead = (timing.wall_seconds * workers - sum(timing.task_seconds)) / args.modules
        print(
            f"{label:<24} {workers:>7} {start:>8} {timing.wall_seconds:>7.2f} {sum(timing.task_seconds):>8.2f} "
            f"{overhead:>18.3f} {'yes' if same else 'NO':>5}"
        )


if __name__ == "__main__":
    main()
