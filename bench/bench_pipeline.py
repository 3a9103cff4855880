"""Whole-pipeline timings: training s/epoch (kernel beside the torch loop) and evaluate on every place, by part.

    OMP_NUM_THREADS=1 python bench/bench_pipeline.py --checkpoint CKPT [--places 0:2400] [--train-places 0:100]

Training: one epoch of the default configuration on --train-places summer images, through the
compiled STDP window and through the torch loop (``train_batch(compiled=False)``), the two
checked to give the same weights; 60 epochs extrapolated (the first epochs cost more than the
later ones: more neurons fire). Evaluation: what ``vprsnn-export evaluate CKPT --query winter``
does on --places, split into decode (PNG + pre-processing), encode (Poisson spikes), network
(float kernel) and readout (every strategy, k=1); the checkpoint's reference places must be
those places (train one with ``--places 0:2400 --epochs 1`` for a timing checkpoint). Each cell
is the best of --repeats runs. Peak memory is this process's maximum resident set.
"""

from __future__ import annotations

import argparse
import resource
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from vprsnn_export.config import Config
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.io.checkpoint import load_checkpoint
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.readout.scoring import readout_rows
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.trainer import train as train_module
from vprsnn_export.trainer.train import Presentation, train_batch, train_network

NORDLAND = Path(__file__).resolve().parents[1].parent / "shared/data/nordland_64x32_summer_winter"


def best_of(run: Callable[[], object], repeats: int) -> tuple[float, object]:
    best, result = float("inf"), None
    for _ in range(repeats):
        started = time.perf_counter()
        result = run()
        best = min(best, time.perf_counter() - started)
    return best, result


def torch_loop_batch(weights, theta, spikes, cfg, compiled=True):
    return train_batch(weights, theta, spikes, cfg, compiled=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=NORDLAND / "places.csv")
    parser.add_argument("--checkpoint", type=Path, help="checkpoint whose reference places are --places")
    parser.add_argument("--places", default="0:2400")
    parser.add_argument("--train-places", default="0:100")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--no-torch-loop", action="store_true", help="skip the (slow) torch-loop training epoch")
    args = parser.parse_args()
    torch.set_num_threads(1)
    cfg = Config()
    one_epoch = cfg.replace(**{"train.epochs": 1})
    train_data = load_dataset(args.data, ["summer"], cfg.preprocess, places=args.train_places)
    images = train_data.traversal("summer")
    presentations = [Presentation("summer", int(p)) for p in train_data.place_ids]
    train_network(images[:2], presentations[:2], one_epoch, device=torch.device("cpu"), progress=False)  # compile

    def one(runner=None):
        original = train_module.train_batch
        if runner is not None:
            train_module.train_batch = runner
        try:
            return train_network(images, presentations, one_epoch, device=torch.device("cpu"), progress=False)
        finally:
            train_module.train_batch = original

    kernel_s, kernel = best_of(one, args.repeats)
    rows = [("train: 1 epoch, compiled kernel", kernel_s), ("train: 60 epochs (x60), compiled kernel", 60 * kernel_s)]
    if not args.no_torch_loop:
        loop_s, loop = best_of(lambda: one(torch_loop_batch), 1)
        assert torch.equal(kernel.weights, loop.weights) and torch.equal(kernel.thresholds, loop.thresholds)
        rows += [("train: 1 epoch, torch loop", loop_s), ("train: 60 epochs (x60), torch loop", 60 * loop_s)]

    if args.checkpoint is not None:
        ckpt = load_checkpoint(args.checkpoint)
        decode_s, dataset = best_of(
            lambda: load_dataset(args.data, ["winter"], ckpt.config.preprocess, places=args.places), args.repeats
        )
        queries = dataset.traversal("winter")
        if not np.array_equal(dataset.place_ids, ckpt.reference_place_ids):
            raise SystemExit(f"the checkpoint's reference places are not --places {args.places}")
        encode_s, spikes = best_of(lambda: query_spikes(queries, dataset.place_ids, "winter", ckpt.config), 1)
        network = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, ckpt.config, torch.device("cpu"))
        network.run(spikes[:1])  # compile or load
        network_s, run = best_of(lambda: network.run(spikes), args.repeats)
        del spikes
        options = SequenceOptions()
        counts = run.counts.numpy()
        readout_s, _ = best_of(
            lambda: readout_rows(
                ckpt.calibration, counts, ckpt.reference_place_ids, dataset.place_ids, options, ckpt.config
            ),
            args.repeats,
        )
        n = len(dataset.place_ids)
        rows += [
            (f"evaluate {n}: decode", decode_s),
            (f"evaluate {n}: encode", encode_s),
            (f"evaluate {n}: network (float kernel)", network_s),
            (f"evaluate {n}: readout", readout_s),
            (f"evaluate {n}: sum of parts", decode_s + encode_s + network_s + readout_s),
        ]
    print(f"threads: torch {torch.get_num_threads()}, kernels serial; best of {args.repeats}")
    print(f"{'part':<44} {'seconds':>8}")
    for name, seconds in rows:
        print(f"{name:<44} {seconds:8.3f}")
    print(f"peak resident memory: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")


if __name__ == "__main__":
    main()
