"""CPU kernels, torch on a device and the dense bound on that device, side by side in one run.

    OMP_NUM_THREADS=1 python bench/bench_device.py [--device cpu|cuda] [--modules 1,24] [--batch 100]
                                                 [--route-batch 20] [--single 5] [--timesteps 300]
                                                 [--train-modules 2] [--train-places 20]

For each ensemble size M in --modules (M modules of network.n_neurons neurons on network.n_inputs inputs, the default config):

* CPU float kernel / CPU integer kernel: the compiled event-driven kernels (vprsnn_export.network.dynamics_kernel, vprsnn_export.targets.intsim_kernel);
* torch float / torch integer on --device: ``run_network(compiled=False)`` and
  ``run_prepared(compiled=False)``, every query of a chunk and every module at once, t sequential;
* dense bound on --device: the input-current matmul alone (spikes @ W, float32), the work a
  dense torch path cannot avoid.

Batched: --batch queries in one call (--route-batch when M > 1, to bound the (chunk, T, M n)
current tensor on a small host); batch 1: one query per call over --single queries. The
weights are synthetic (STDP initial weights per module, thresholds theta_init; the integer
model is their 8-bit per-neuron quantisation): the cost per step of every path does not depend
on the values, so throughputs hold for trained networks; spike counts do not. The integer torch
path on the device is checked to equal the CPU kernel (every SpikeRun field) in the same run.
Training: --train-modules modules of --train-places synthetic places, one epoch, by
``train_modules`` with the CPU kernel and with the torch path on --device.
Dense FLOPs per query are 2 T inputs M n (currents) + ~6 T M n (neuron updates): the model for
devices not measured. Each cell is one run after a warm-up (the machine may be shared: the
load average is printed); peak device memory is printed on CUDA.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

import numpy as np
import torch

from vprsnn_export.config import Config
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.export.quantize import QuantiseOptions, quantize_checkpoint
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.network.dynamics import input_currents, run_network
from vprsnn_export.network.dynamics_kernel import float_run
from vprsnn_export.targets.intsim import prepare, run_prepared
from vprsnn_export.trainer.batched import module_training_rows, train_modules
from vprsnn_export.trainer.stdp import initial_weights
from vprsnn_export.trainer.train import Presentation


def ensemble(modules: int, cfg: Config) -> Checkpoint:
    """An untrained ensemble of ``modules`` modules (one place each): synthetic weights, theta_init."""
    cfg = cfg.replace(**{"train.module_size": 1 if modules > 1 else 0})
    n, inputs = cfg.network.n_neurons, cfg.network.n_inputs
    weights = np.concatenate(
        [initial_weights(inputs, n, torch.Generator().manual_seed(m)).numpy() for m in range(modules)], axis=1
    )
    return Checkpoint(
        config=cfg,
        weights=weights,
        thresholds=np.full(modules * n, cfg.network.theta_init, dtype=np.float32),
        calibration=np.zeros((modules * n, modules), dtype=np.int64),
        reference_place_ids=np.arange(modules, dtype=np.int64),
        reference_traversals=["summer"],
        data={"source": "synthetic weights"},
    )


def seconds(run: Callable[[], object], device: torch.device) -> float:
    if device.type == "cuda":
        torch.cuda.synchronize()
    started = time.perf_counter()
    run()
    if device.type == "cuda":
        torch.cuda.synchronize()
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cpu", choices=("cpu", "cuda"))
    parser.add_argument("--modules", default="1,24", help="ensemble sizes, e.g. 1,24")
    parser.add_argument("--batch", type=int, default=100, help="queries per batched call, one module")
    parser.add_argument("--route-batch", type=int, default=20, help="queries per batched call, M > 1")
    parser.add_argument("--single", type=int, default=5, help="queries timed one per call")
    parser.add_argument("--timesteps", type=int, default=300)
    parser.add_argument("--train-modules", type=int, default=2, help="0: skip the training rows")
    parser.add_argument("--train-places", type=int, default=20, help="places per training module")
    args = parser.parse_args()
    torch.set_num_threads(1)
    device, cpu = torch.device(args.device), torch.device("cpu")
    cfg = Config().replace(**{"encoder.timesteps": args.timesteps})
    rows: list[tuple] = []
    exact: list[str] = []
    for modules in (int(m) for m in args.modules.split(",")):
        ckpt = ensemble(modules, cfg)
        mcfg = ckpt.config
        n_queries = args.batch if modules == 1 else args.route_batch
        images = np.random.default_rng(7).random((n_queries, mcfg.network.n_inputs)).astype(np.float32)
        spikes = query_spikes(images, np.arange(n_queries), "winter", mcfg)
        model = quantize_checkpoint(ckpt, "0" * 64, 8, QuantiseOptions())
        w_cpu = torch.from_numpy(ckpt.weights)
        th_cpu = torch.from_numpy(ckpt.thresholds)
        w_dev, th_dev = w_cpu.to(device), th_cpu.to(device)
        prep_cpu, prep_dev = prepare(model, cpu), prepare(model, device)
        group, beta = mcfg.network.n_neurons, mcfg.network.beta
        paths: dict[str, tuple[torch.device, Callable[[torch.Tensor], object]]] = {
            "CPU float kernel": (cpu, lambda s: float_run(s, w_cpu, th_cpu, beta=beta, group=group)),
            "CPU integer kernel": (cpu, lambda s: run_prepared(prep_cpu, s, isolation=True, record=False)),
            f"torch float on {device}": (
                device,
                lambda s: run_network(s, w_dev, th_dev, beta=beta, compiled=False, group=group),
            ),
            f"torch integer on {device}": (
                device,
                lambda s: run_prepared(prep_dev, s, isolation=True, record=False, compiled=False),
            ),
            f"dense bound on {device}": (device, lambda s: input_currents(s.to(device), w_dev)),
        }
        kernel = run_prepared(prep_cpu, spikes, isolation=True, record=True)
        loop = run_prepared(prep_dev, spikes, isolation=True, record=True, compiled=False)
        same = all(
            torch.equal(getattr(kernel, f), getattr(loop, f))
            for f in ("counts", "raster", "candidates_per_step", "final_voltage")
        ) and (kernel.saturations, kernel.max_current) == (loop.saturations, loop.max_current)
        exact.append(f"M={modules}: torch integer on {device} == CPU integer kernel (every field): {same}")
        flops = 2 * args.timesteps * mcfg.network.n_inputs * modules * group + 6 * args.timesteps * modules * group
        for name, (where, run) in paths.items():
            run(spikes[:1])  # warm-up: numba loads its cache, CUDA initialises
            if where.type == "cuda":
                torch.cuda.reset_peak_memory_stats()
            batch_s = seconds(lambda: run(spikes), where)
            peak = torch.cuda.max_memory_allocated() / 2**20 if where.type == "cuda" else None
            singles = [spikes[i : i + 1] for i in range(min(args.single, n_queries))]
            single_s = seconds(lambda: [run(one) for one in singles], where) / len(singles)
            rows.append((modules, name, n_queries, n_queries / batch_s, 1e3 * single_s, peak, flops))
    print(
        f"device {device}; T={args.timesteps}; n={cfg.network.n_neurons} neurons per module; synthetic weights; "
        f"torch threads {torch.get_num_threads()}; load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores\n"
    )
    print("| modules | path | batch | batched q/s | batch 1 ms/query | peak device MiB | dense GFLOP/query |")
    print("|---|---|---|---|---|---|---|")
    for modules, name, batch, rate, single_ms, peak, flops in rows:
        memory = "-" if peak is None else f"{peak:.0f}"
        print(f"| {modules} | {name} | {batch} | {rate:.1f} | {single_ms:.2f} | {memory} | {flops / 1e9:.2f} |")
    print("\n" + "\n".join(exact))
    if args.train_modules:
        places = args.train_modules * args.train_places
        tcfg = cfg.replace(**{"train.epochs": 1, "train.module_size": args.train_places})
        images = np.random.default_rng(8).random((places, cfg.network.n_inputs)).astype(np.float32)
        presentations = [Presentation("summer", p) for p in range(places)]
        train_rows = module_training_rows(places, args.train_places, 1)
        for label, where, compiled in (("CPU kernel", cpu, True), (f"torch on {device}", device, False)):
            train_modules(images[:8], presentations[:8], [np.arange(8)], tcfg, device=where, progress=False)
            spent = seconds(
                lambda: train_modules(
                    images, presentations, train_rows, tcfg, device=where, progress=False, compiled=compiled
                ),
                where,
            )
            print(
                f"training, {label}: {args.train_modules} modules x {args.train_places} places, 1 epoch, "
                f"T={args.timesteps}: {spent:.2f} s ({spent / places:.3f} s per place-epoch)"
            )


if __name__ == "__main__":
    main()
