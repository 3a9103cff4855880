"""A long route's end-to-end time, modelled from costs measured on this machine at the route's own width.

A route of L places in modules of P has M = L / P modules of n neurons. Training is O(L): each module learns its
own P places, so ``--epochs`` epochs of ``--modules`` modules of a synthetic route give the cost of a module's
first epoch and of a later one.
Calibration and a query traversal are O(L^2 / P): each of L presentations runs through all M n neurons (one WTA
over them, the preset's ``network.wta_scope``), so ``--presentations`` real encoded presentations are run through
weights of the route's full width, which measures what the full width costs in cache and memory. The readout
(W+Prob at k = 1 / 5 / 10 in query blocks) is timed on ``--readout-queries`` queries of a lean-shaped route of
that width (``bench_scale.py``'s synthetic counts). Each phase is the measured cost times its count::

    train     = M x (first epoch + (epochs - 1) x later epoch)
    calibrate = L x (presentation at width M n)
    evaluate  = L x (presentation at width M n) + L x (readout per query at width L)

Memory is the library's own model of each phase (``resources.training_need``, ``calibration_need``,
``run_need`` with the long-route blocks), the loaded data aside. Prints the measured costs and a row per modelled route.

    python bench/bench_route_model.py --threads 2 [--preset lean] [--places 27000,100000] [--modules 40] [--epochs 3]
        [--module-size P] [--presentations 96]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from bench_scale import KS, route_counts

from vprsnn_export.config import preset
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.data.truth import EXACT
from vprsnn_export.network.dynamics_kernel import QUERY_CHUNK, float_run
from vprsnn_export.readout.scoring import READOUT_BLOCK, Readout
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.readout.strategies import STRATEGIES
from vprsnn_export.resources import run_need, training_need
from vprsnn_export.runtime.evaluation import LONG_ROUTE_BLOCK
from vprsnn_export.threads import set_threads
from vprsnn_export.trainer.batched import module_training_rows, train_modules
from vprsnn_export.trainer.calibrate import calibration_need
from vprsnn_export.trainer.train import Presentation

GIB = 2**30


def module_epoch_seconds(cfg, modules: int, epochs: int, threads: int) -> tuple[float, float]:
    """Seconds per module of the first training epoch and of each later one (their mean), ``modules`` modules of
    a synthetic route trained for ``epochs`` epochs (the first epochs, where most neurons fire, cost the most)."""
    places = modules * cfg.train.module_size
    data = load_dataset(f"synthetic:{places}", ["summer"], cfg.preprocess)
    rows = module_training_rows(places, cfg.train.module_size, 1)
    presentations = [Presentation("summer", int(p)) for p in data.place_ids]
    timed = cfg.replace(**{"train.epochs": epochs})
    kwargs = {"device": torch.device("cpu"), "progress": False, "threads": threads}
    train_modules(data.traversal("summer"), presentations, rows[:1], cfg.replace(**{"train.epochs": 1}), **kwargs)
    seconds = [entry["seconds"] / modules for entry in train_modules(
        data.traversal("summer"), presentations, rows, timed, **kwargs).history]  # fmt: skip
    return seconds[0], float(np.mean(seconds[1:])) if len(seconds) > 1 else seconds[0]


def presentation_seconds(cfg, spikes: torch.Tensor, neurons: int, threads: int) -> float:
    """Seconds per presentation through ``neurons`` neurons in one WTA group (random weights, the real spikes)."""
    rng = np.random.default_rng(neurons)
    weights = (rng.random((cfg.network.n_inputs, neurons), dtype=np.float32) * 0.02).astype(np.float32)
    theta = np.full(neurons, 1.0, dtype=np.float32)
    float_run(spikes[:2], weights, theta, beta=cfg.network.beta, threads=threads)  # compiled before the timing
    began = time.perf_counter()
    float_run(spikes, weights, theta, beta=cfg.network.beta, threads=threads)
    return (time.perf_counter() - began) / len(spikes)


def readout_seconds(cfg, places: int, queries: int) -> float:
    """Seconds per query of the block readout (W+Prob, k = 1 / 5 / 10) on a lean-shaped route of ``places``."""
    sr, counts = route_counts(places, np.random.default_rng(places))
    queries = min(queries, places)
    ids = np.arange(places)
    readout = Readout.of(sr, cfg.replace(**{"network.n_neurons": cfg.train.module_size}), SequenceOptions(ks=KS))
    began = time.perf_counter()
    readout.score_in_blocks(counts[:queries], ids, ids[:queries], EXACT)
    return (time.perf_counter() - began) / queries


def memory(cfg, places: int, threads: int) -> tuple[float, float, float]:
    """GiB the library's memory model gives training, calibration and evaluation of a route of ``places``."""
    modules = places // cfg.train.module_size
    neurons = modules * cfg.network.n_neurons
    train = training_need(n_modules=modules, n_inputs=cfg.network.n_inputs, n_neurons=cfg.network.n_neurons,
                          timesteps=cfg.training_encoder.timesteps, batch=min(cfg.train.batch_size,
                          cfg.train.module_size), threads=threads)  # fmt: skip
    calibrate = calibration_need(cfg, places, neurons, places)
    evaluate = run_need(presentations=places, timesteps=cfg.encoder.timesteps, n_inputs=cfg.network.n_inputs,
                        n_neurons=neurons, places=places, chunk=QUERY_CHUNK, rate_scale=cfg.encoder.rate_scale,
                        readout_rows=READOUT_BLOCK + max(KS), readout_arrays=len(STRATEGIES.names()) + len(KS) + 2,
                        block=LONG_ROUTE_BLOCK)  # as runtime.evaluation._prepared asks it  # fmt: skip
    return train.total / GIB, calibrate.total / GIB, evaluate.total / GIB


def minutes(seconds: float) -> str:
    return f"{seconds / 60:.1f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="lean")
    parser.add_argument("--places", default="27000,100000", help="route lengths to model, comma-separated")
    parser.add_argument("--module-size", type=int, help="places per module (default: the preset's, else 100)")
    parser.add_argument("--modules", type=int, default=40, help="modules trained for one epoch to time a module-epoch")
    parser.add_argument("--epochs", type=int, default=3, help="epochs timed (at least 2: the first costs the most)")
    parser.add_argument("--presentations", type=int, default=96, help="presentations timed at each route's width")
    parser.add_argument("--readout-queries", type=int, default=2048)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    set_threads(args.threads)
    cfg = preset(args.preset)
    cfg = cfg.replace(**{"train.module_size": args.module_size or cfg.train.module_size or 100})
    routes = [int(p) for p in args.places.split(",")]
    sample = load_dataset(f"synthetic:{args.presentations}", ["winter"], cfg.preprocess)
    spikes = query_spikes(sample.traversal("winter"), sample.place_ids, "winter", cfg)
    inputs = float(spikes.sum()) / len(spikes)
    first, later = module_epoch_seconds(cfg, args.modules, args.epochs, args.threads)
    print(f"preset {args.preset}: modules of {cfg.train.module_size} places, {cfg.network.n_neurons} neurons each, "
          f"{cfg.train.epochs} epochs, T = {cfg.encoder.timesteps}; {args.threads} thread(s)")  # fmt: skip
    print(f"measured: a module-epoch {first:.3f} s (the first), {later:.3f} s (the next {args.epochs - 1}; "
          f"{args.modules} modules); "
          f"{inputs:.0f} input spikes per presentation")  # fmt: skip
    print(
        "\n| places | neurons | s per presentation (measured) | readout ms per query (measured) | events per "
        "query | train min | calibrate min | evaluate min | end to end min | GiB train / calibrate / evaluate |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    for places in routes:
        modules = places // cfg.train.module_size
        neurons = modules * cfg.network.n_neurons
        per_presentation = presentation_seconds(cfg, spikes, neurons, args.threads)
        per_query = readout_seconds(cfg, places, args.readout_queries)
        train = modules * (first + (cfg.train.epochs - 1) * later)
        calibrate = places * per_presentation
        evaluate = places * (per_presentation + per_query)
        gib = memory(cfg, places, args.threads)
        print(f"| {places:,} | {neurons:,} | {per_presentation:.4f} | {1000 * per_query:.2f} | "
              f"{inputs * neurons / 1e6:.0f} M | {minutes(train)} | {minutes(calibrate)} | {minutes(evaluate)} | "
              f"{minutes(train + calibrate + evaluate)} | {' / '.join(f'{g:.1f}' for g in gib)} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
