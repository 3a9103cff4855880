"""Throughput of the integer simulator beside the float path, measured side by side in one run.

    python bench/bench_intsim.py [--checkpoint CKPT] [--repeats 5]

Both paths get the same spike trains (100 queries batched, encoded outside the
timing) at T=150 and T=300. Without a checkpoint the network is the untrained
784x400 network (initial STDP weights, theta_init), which costs the same per step.
Queries come from the real Nordland subset when it is present, else the synthetic
route. Each cell is the best of --repeats runs, float and integer alternating.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from vprsnn_export.config import Config
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.export.quantize import QuantiseOptions, quantize_checkpoint
from vprsnn_export.io.checkpoint import Checkpoint, checkpoint_sha256, load_checkpoint
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.targets.intsim import IntegerNetwork
from vprsnn_export.trainer.stdp import initial_weights

NORDLAND = Path(__file__).resolve().parents[1].parent / "shared/data/nordland_64x32_summer_winter"


def untrained_checkpoint(cfg: Config) -> Checkpoint:
    weights = initial_weights(cfg.network.n_inputs, cfg.network.n_neurons, torch.Generator().manual_seed(0)).numpy()
    n = cfg.network.n_neurons
    return Checkpoint(
        config=cfg,
        weights=weights,
        thresholds=np.full(n, cfg.network.theta_init, dtype=np.float32),
        calibration=np.zeros((n, 1), dtype=np.int64),
        reference_place_ids=np.zeros(1, dtype=np.int64),
        reference_traversals=["summer"],
        data={},
    )


def _timed(run) -> float:
    started = time.perf_counter()
    run()
    return time.perf_counter() - started


def query_images(preprocess) -> tuple[str, np.ndarray, np.ndarray]:
    if (NORDLAND / "subset_100_places.csv").is_file():
        data = load_dataset(NORDLAND / "places.csv", ["winter"], preprocess, subset=NORDLAND / "subset_100_places.csv")
        source = "Nordland 100-place subset, winter"
    else:
        data = load_dataset("synthetic:100", ["winter"], preprocess)
        source = "synthetic route (Nordland subset absent), winter"
    return source, data.traversal("winter"), data.place_ids


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", help="trained float checkpoint (default: an untrained 784x400 network)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--bits", type=int, default=8)
    args = parser.parse_args()
    ckpt = load_checkpoint(args.checkpoint) if args.checkpoint else untrained_checkpoint(Config())
    digest = checkpoint_sha256(args.checkpoint) if args.checkpoint else "0" * 64
    source, images, place_ids = query_images(ckpt.config.preprocess)
    device = torch.device("cpu")
    float_net = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, ckpt.config, device)
    integer = {
        scheme: IntegerNetwork(
            quantize_checkpoint(ckpt, digest, args.bits, QuantiseOptions(per_neuron=scheme == "per-neuron")), device
        )
        for scheme in ("per-tensor", "per-neuron")
    }
    print(
        f"queries: {len(place_ids)} from the {source}; {torch.get_num_threads()} torch threads; "
        f"{args.bits}-bit models; best of {args.repeats}\n"
    )
    header = "| T | float q/s | integer per-tensor q/s | ratio | integer per-neuron q/s | ratio |"
    print(header)
    print("|---|---|---|---|---|---|")
    for timesteps in (150, 300):
        cfg = ckpt.config.replace(**{"encoder.timesteps": timesteps})
        spikes = query_spikes(images, place_ids, "winter", cfg)
        runs = {"float": lambda: float_net.run(spikes)}
        runs.update({scheme: (lambda net=net: net.run(spikes)) for scheme, net in integer.items()})
        for run in runs.values():
            run()  # warm-up
        best = {name: float("inf") for name in runs}
        for _ in range(args.repeats):
            for name, run in runs.items():
                best[name] = min(best[name], _timed(run))
        rate = {name: len(place_ids) / seconds for name, seconds in best.items()}
        print(
            f"| {timesteps} | {rate['float']:.0f} | {rate['per-tensor']:.0f} | {rate['per-tensor'] / rate['float']:.2f} "
            f"| {rate['per-neuron']:.0f} | {rate['per-neuron'] / rate['float']:.2f} |"
        )


if __name__ == "__main__":
    main()
