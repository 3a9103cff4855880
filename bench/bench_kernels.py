"""The compiled event-driven kernels beside today's torch paths and the dense-BLAS bound, side by side in one run.

    OMP_NUM_THREADS=1 python bench/bench_kernels.py [--checkpoint CKPT] [--repeats 3] [--timesteps 300]

Every path gets the same query spike trains (encoded outside the timings; the encoder's
cost is printed on its own). Batch 100: the 100 queries in one call; batch 1: one query
per call, over --single queries. The dense-BLAS bound is the input-current matmul alone
(spikes (N, T, 784) @ W (784, 400) in float32), the work the torch paths cannot avoid.
Without a checkpoint the network is the untrained 784x400 one (same cost per step).
The integer model is the 8-bit per-neuron quantisation. Each cell is the best of
--repeats runs, the paths alternating; compare ratios, not absolute figures, on a
loaded machine. The kernels' outputs are checked against today's paths in the same run.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np
import torch
from bench_intsim import untrained_checkpoint  # the sibling script (bench/ is on sys.path when run)

from vprsnn_export.config import Config, PreprocessConfig
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.encoding import encode, presentation_seed, query_spikes
from vprsnn_export.export.quantize import QuantiseOptions, quantize_checkpoint
from vprsnn_export.io.checkpoint import checkpoint_sha256, load_checkpoint
from vprsnn_export.network.dynamics import FloatNetwork, input_currents, run_network
from vprsnn_export.network.dynamics_kernel import float_run
from vprsnn_export.network.runs import SpikeRun
from vprsnn_export.targets.intsim import IntegerNetwork, run_prepared
from vprsnn_export.targets.intsim_kernel import integer_run
from vprsnn_export.trainer.stdp import initial_weights
from vprsnn_export.trainer.stdp_kernel import stdp_window
from vprsnn_export.trainer.train import train_batch

NORDLAND = Path(__file__).resolve().parents[1].parent / "shared/data/nordland_64x32_summer_winter"


def query_images(preprocess: PreprocessConfig, data: Path) -> tuple[str, np.ndarray, np.ndarray]:
    """The 100 winter queries of the Nordland subset in ``data``, else of the synthetic route."""
    if (data / "subset_100_places.csv").is_file():
        dataset = load_dataset(data / "places.csv", ["winter"], preprocess, subset=data / "subset_100_places.csv")
        source = f"Nordland 100-place subset ({data}), winter"
    else:
        dataset = load_dataset("synthetic:100", ["winter"], preprocess)
        source = "synthetic route (Nordland subset absent), winter"
    return source, dataset.traversal("winter"), dataset.place_ids


@dataclass(frozen=True)
class Timing:
    batch_rate: float  # queries/s, all queries in one call
    single_ms: float  # ms per query, one query per call


def best_of(run: Callable[[], object], repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        started = time.perf_counter()
        run()
        best = min(best, time.perf_counter() - started)
    return best


def integer_kernel_runner(network: IntegerNetwork) -> Callable[[torch.Tensor], SpikeRun]:
    prep = network.prepared
    mantissas = network.model.weight_mantissa
    threshold = prep.threshold.numpy()
    multipliers = None if prep.multipliers is None else prep.multipliers.numpy()

    def run(spikes: torch.Tensor) -> SpikeRun:
        return integer_run(
            spikes,
            mantissas,
            threshold,
            multipliers,
            keep=prep.keep,
            limit=prep.limit,
            shift=prep.shift,
            wta=prep.wta,
        )

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", help="trained float checkpoint (default: an untrained 784x400 network)")
    parser.add_argument("--data", type=Path, default=NORDLAND, help="the Nordland folder (default: %(default)s)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--timesteps", type=int, default=300)
    parser.add_argument("--single", type=int, default=20, help="queries timed one by one for batch 1")
    parser.add_argument("--no-train", action="store_true", help="skip the training-window comparison")
    args = parser.parse_args()
    torch.set_num_threads(1)
    ckpt = load_checkpoint(args.checkpoint) if args.checkpoint else untrained_checkpoint(Config())
    digest = checkpoint_sha256(args.checkpoint) if args.checkpoint else "0" * 64
    cfg = ckpt.config.replace(**{"encoder.timesteps": args.timesteps})
    source, images, place_ids = query_images(cfg.preprocess, args.data)
    started = time.perf_counter()
    spikes = query_spikes(images, place_ids, "winter", cfg)
    encode_ms = 1e3 * (time.perf_counter() - started) / len(place_ids)
    n = len(place_ids)
    device = torch.device("cpu")
    float_net = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, cfg, device)
    integer = IntegerNetwork(quantize_checkpoint(ckpt, digest, 8, QuantiseOptions()), device)
    run_integer_kernel = integer_kernel_runner(integer)
    weights, thresholds = float_net.weights, float_net.thresholds
    beta = cfg.network.beta

    def torch_float(s: torch.Tensor) -> SpikeRun:
        return run_network(s, weights, thresholds, beta=beta, wta=cfg.network.wta, compiled=False)

    def torch_integer(s: torch.Tensor) -> SpikeRun:
        return run_prepared(integer.prepared, s, isolation=True, record=False, compiled=False)

    paths: dict[str, Callable[[torch.Tensor], object]] = {
        "float path, torch loop (run_network compiled=False)": torch_float,
        "integer simulator, torch loop (compiled=False)": torch_integer,
        "float kernel": lambda s: float_run(s, weights, thresholds, beta=beta, wta=cfg.network.wta),
        "integer kernel": run_integer_kernel,
        "dense-BLAS bound (currents matmul only)": lambda s: input_currents(s, weights),
    }
    # warm-up (numba compiles or loads its cache here) and the exactness check of this run
    float_same = torch.equal(torch_float(spikes).counts, float_run(spikes, weights, thresholds, beta=beta).counts)
    reference, kernel = torch_integer(spikes), run_integer_kernel(spikes)
    integer_same = all(
        torch.equal(getattr(reference, f), getattr(kernel, f))
        for f in ("counts", "candidates_per_step", "final_voltage")
    ) and (reference.saturations, reference.max_current) == (kernel.saturations, kernel.max_current)
    for run in paths.values():
        run(spikes[:1])
    batch_best = {name: float("inf") for name in paths}
    single_best = {name: float("inf") for name in paths}
    singles = [spikes[i : i + 1] for i in range(min(args.single, n))]
    for _ in range(args.repeats):
        for name, run in paths.items():
            batch_best[name] = min(batch_best[name], best_of(lambda run=run: run(spikes), 1))
            single_best[name] = min(
                single_best[name], best_of(lambda run=run: [run(one) for one in singles], 1) / len(singles)
            )
    timings = {name: Timing(n / batch_best[name], 1e3 * single_best[name]) for name in paths}
    bound = timings["dense-BLAS bound (currents matmul only)"]
    load = os.getloadavg()[0]
    print(
        f"queries: {n} from the {source}; T={args.timesteps}; torch threads {torch.get_num_threads()}, "
        f"numba kernels serial (threading layer never launched; NUMBA_NUM_THREADS="
        f"{numba.config.NUMBA_NUM_THREADS}), OMP_NUM_THREADS="
        f"{os.environ.get('OMP_NUM_THREADS', 'unset')}; load average {load:.2f} on {os.cpu_count()} cores; "
        f"best of {args.repeats}\n"
    )
    print("| path | batch 100 q/s | x dense bound | batch 1 ms/query | batch 1 q/s | x dense bound |")
    print("|---|---|---|---|---|---|")
    for name, timing in timings.items():
        print(
            f"| {name} | {timing.batch_rate:.0f} | {timing.batch_rate / bound.batch_rate:.2f} "
            f"| {timing.single_ms:.2f} | {1e3 / timing.single_ms:.0f} | {bound.single_ms / timing.single_ms:.2f} |"
        )
    today_f = timings["float path, torch loop (run_network compiled=False)"]
    today_i = timings["integer simulator, torch loop (compiled=False)"]
    kernel_f, kernel_i = timings["float kernel"], timings["integer kernel"]
    print(
        f"\nspeed-up, batch 100: float {kernel_f.batch_rate / today_f.batch_rate:.1f}x, "
        f"integer {kernel_i.batch_rate / today_i.batch_rate:.1f}x; batch 1: float "
        f"{today_f.single_ms / kernel_f.single_ms:.1f}x, integer {today_i.single_ms / kernel_i.single_ms:.1f}x"
    )
    print(
        f"encoder (query_spikes, torch RNG): {encode_ms:.2f} ms per query at T={args.timesteps} "
        f"({1e3 / encode_ms:.0f} queries/s), not included above"
    )
    print(f"kernel counts identical to today's: float {float_same}, integer (every SpikeRun field) {integer_same}")
    if not args.no_train:
        train_cfg = cfg.replace(**{"encoder.timesteps": args.timesteps})
        batch = train_cfg.train.batch_size
        rows = np.arange(min(batch, n))
        seeds = [presentation_seed(cfg.seed, "train", "summer", int(place_ids[r]), 0) for r in rows]
        window = encode(images[rows], seeds, train_cfg.encoder)
        start = initial_weights(784, 400, torch.Generator().manual_seed(0))  # the first batch of a training run
        theta = torch.full((400,), train_cfg.network.theta_init)
        stdp_window(start, theta, window[:, :2], train_cfg)  # compile or load
        torch_s = best_of(lambda: train_batch(start, theta, window, train_cfg), 1)
        kernel_s = best_of(lambda: stdp_window(start, theta, window, train_cfg), 1)
        compiled = stdp_window(start, theta, window, train_cfg)
        same = compiled is not None and torch.equal(compiled[0], train_batch(start, theta, window, train_cfg)[0])
        print(
            f"training window ({len(rows)} presentations x T={args.timesteps}, plasticity on): torch loop "
            f"{torch_s:.2f} s, compiled {kernel_s:.2f} s ({torch_s / kernel_s:.1f}x); weights identical: {same}"
        )


if __name__ == "__main__":
    main()
