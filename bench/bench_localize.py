"""Per-frame latency and memory of `localize` (runtime.localize.Localizer) for one module and an ensemble.

    OMP_NUM_THREADS=1 python bench/bench_localize.py [--frames 30] [--modules 24[,100,...]] [--module-size 100]
                                                   [--backends float,integer,onnx] [--k 1,5] [--preset NAME,...]
                                                   [--search-window PLACES]

SYNTHETIC networks and frames (no training, no data set): each preset's configuration (the default: dog; lean
runs 100 neurons per module at T = 80: one row per preset, side by side in one run)
(``network.n_neurons`` neurons per module, DoG inputs, T = ``encoder.timesteps``) with random
weights in [0, w_max], thresholds 2.0 and random calibration counts, as (a) one module of
--module-size places and (b) an ensemble of --modules modules (--modules x --module-size places,
WTA per module, the region regularisation in the readout). Latency depends on the network's
size, not on what it learnt; accuracy is not measured here. Frames are random 32 x 64 greyscale
images pushed one at a time (``Localizer.push``: preprocessing, encoding, the network, the
readout and the sequence aggregation; k = 5 tracks the velocity over 0.5:1.5:0.1). The first
--warmup frames are dropped. Memory: the process's resident set (VmRSS) after the localiser
is built and its peak (VmHWM) after the frames, in MiB (the process holds every network built
before: read the growth). The machine may be shared: the load average is printed.

``--search-window PLACES`` adds, for every ensemble and the float and integer backends, the rows of a localiser
tracking within that window (``runtime.localize.SearchWindow``) with every decided frame accepted (threshold 0),
so that after the first (global, dropped with the warm-up) every frame runs the window's modules alone: the cost
of a tracked frame against the route's length (``--modules 24,100``). ``events``: synaptic events per frame,
input spikes x the neurons that ran.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from vprsnn_export.config import PRESETS, preset
from vprsnn_export.export.quantize import QuantiseOptions, quantize_checkpoint
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.localize import Localizer, SearchWindow
from vprsnn_export.targets.onnx_target import write_onnx
from vprsnn_export.threads import set_threads


def memory_mib(field: str) -> float:
    """VmRSS / VmHWM of this process in MiB (Linux), NaN elsewhere."""
    status = Path("/proc/self/status")
    if not status.exists():
        return float("nan")
    for line in status.read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    return float("nan")


def random_checkpoint(modules: int, module_size: int, name: str = "dog", seed: int = 0) -> Checkpoint:
    cfg = preset(name).replace(**{"train.module_size": module_size if modules > 1 else 0})
    rng = np.random.default_rng(seed)
    n_places = modules * module_size
    neurons = modules * cfg.network.n_neurons
    weights = rng.uniform(0, cfg.stdp.w_max, (cfg.network.n_inputs, neurons)).astype(np.float32)
    return Checkpoint(
        config=cfg,
        weights=weights,
        thresholds=np.full(neurons, 2.0, dtype=np.float32),
        calibration=rng.poisson(0.3, (neurons, n_places)).astype(np.int64),
        reference_place_ids=np.arange(n_places, dtype=np.int64),
        reference_traversals=["summer"],
        data={"source": "synthetic (random weights)"},
    )


def bench(localizer: Localizer, frames: np.ndarray, warmup: int) -> tuple[float, float, float, float]:
    """Median and 95th percentile latency (ms) over the frames after ``warmup``, the mean wall time per frame and
    the mean synaptic events per frame after ``warmup`` (NaN without a search window)."""
    began = time.perf_counter()
    decisions = [localizer.push(frame) for frame in frames]
    wall = 1000 * (time.perf_counter() - began) / len(frames)
    kept = np.asarray([d.latency_ms for d in decisions[warmup:]])
    events = [d.events for d in decisions[warmup:] if d.events is not None]
    return float(np.median(kept)), float(np.percentile(kept, 95)), wall, float(np.mean(events)) if events else np.nan


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--modules", default="24", help="ensembles to time, modules each, comma-separated")
    parser.add_argument("--module-size", type=int, default=100)
    parser.add_argument("--backends", default="float,integer,onnx")
    parser.add_argument("--k", default="1,5")
    parser.add_argument("--preset", default="dog", help=f"presets to time, comma-separated ({', '.join(PRESETS)})")
    parser.add_argument("--search-window", type=int, default=0, help="also track within PLACES places (0: not)")
    args = parser.parse_args()
    presets = args.preset.split(",")
    if not set(presets) <= set(PRESETS):
        parser.error(f"--preset: choose from {', '.join(PRESETS)}")
    set_threads(1)
    backends = args.backends.split(",")
    ks = [int(k) for k in args.k.split(",")]
    rng = np.random.default_rng(1)
    frames = rng.integers(0, 256, (args.frames, 32, 64), dtype=np.uint8)
    print(
        f"load average {os.getloadavg()[0]:.1f}; {args.frames} synthetic frames, first {args.warmup} dropped; "
        f"one module of {args.module_size} places and {args.modules} x {args.module_size} places"
    )
    header = (
        f"{'network':<34} {'backend':<8} {'window':>6} {'k':>2} {'median ms':>10} {'p95 ms':>8} {'wall ms':>8} "
        f"{'events M':>8} {'RSS MiB':>8} {'peak MiB':>9}"
    )
    print(header)
    print("-" * len(header))
    with tempfile.TemporaryDirectory() as tmp:
        ensembles = [int(m) for m in args.modules.split(",")]
        for name, modules in ((name, modules) for name in presets for modules in (1, *ensembles)):
            ckpt = random_checkpoint(modules, args.module_size, name)
            model = quantize_checkpoint(ckpt, "0" * 64, 8, QuantiseOptions())
            graph = write_onnx(model, Path(tmp) / f"{name}{modules}.onnx") if "onnx" in backends else None
            label = f"{name}: {modules} x {ckpt.config.network.n_neurons} n, T={ckpt.config.encoder.timesteps}"
            windows = [0, args.search_window] if args.search_window and modules > 1 else [0]
            for backend, window in ((b, w) for b in backends for w in windows if not (w and b == "onnx")):
                for k in ks:
                    grid = None if k == 1 else tuple(np.round(np.arange(0.5, 1.51, 0.1), 2))
                    options = SequenceOptions(ks=(k,), velocity_candidates=grid, velocity_estimate="track")
                    network = ckpt if backend == "float" else model
                    onnx = graph if backend == "onnx" else None
                    search = {"search": SearchWindow(window), "threshold": 0.0} if window else {}
                    localizer = Localizer(
                        network, backend=backend, options=options, onnx_path=onnx, threads=1, **search
                    )
                    rss = memory_mib("VmRSS")
                    median, p95, wall, events = bench(localizer, frames, args.warmup)
                    print(
                        f"{label:<34} {backend:<8} {window or '-':>6} {k:>2} {median:>10.1f} {p95:>8.1f} {wall:>8.1f} "
                        f"{events / 1e6:>8.2f} {rss:>8.0f} {memory_mib('VmHWM'):>9.0f}"
                    )


if __name__ == "__main__":
    main()
