"""One WTA over a whole ensemble: its currents summed as one tile against column blocks, side by side in one run.

With ``network.wta_scope = ensemble`` (the default) a route's every neuron is one WTA group, so the float and
integer kernels run it as one tile of all its neurons. Summed as one block, every input spike reads a weight row
of the whole route from memory for every presentation; in column blocks of ``TILE_NEURONS`` for
``CURRENT_BYTES`` of presentations at once (:func:`vprsnn_export.network.parallel.current_blocks`), each block's
weights are read from cache for all of them. Same spikes and weights for both (uniform weights, thresholds that
let about half the neurons be candidates per step, the lean preset's input rate); the counts, candidates and
final voltages are checked equal in the same run. Each cell is the best of ``--repeats``.

    python bench/bench_wide_group.py --threads 2 [--neurons 2400,9600,27000] [--presentations 96] [--repeats 2]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from vprsnn_export.network import parallel
from vprsnn_export.network.dynamics_kernel import float_run
from vprsnn_export.threads import set_threads

INPUTS, STEPS, RATE = 1568, 80, 4100 / (80 * 1568)  # the lean preset: DoG ON/OFF 28 x 28, T = 80, ~4,100 spikes


def timed(spikes, weights, theta, tile_neurons: int, repeats: int):
    """(best seconds, run) of the float kernel with ``TILE_NEURONS`` = ``tile_neurons``."""
    kept = parallel.TILE_NEURONS
    parallel.TILE_NEURONS = tile_neurons
    try:
        best, run = float("inf"), None
        for _ in range(repeats):
            began = time.perf_counter()
            run = float_run(spikes, weights, theta, beta=0.9)
            best = min(best, time.perf_counter() - began)
        return best, run
    finally:
        parallel.TILE_NEURONS = kept


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--neurons", default="2400,9600,27000", help="neurons of the one WTA group, comma-separated")
    parser.add_argument("--presentations", type=int, default=96)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    set_threads(args.threads)
    rng = np.random.default_rng(0)
    spikes = (rng.random((args.presentations, STEPS, INPUTS)) < RATE).astype(np.uint8)
    print(f"{args.presentations} presentations x {STEPS} steps x {INPUTS} inputs, {torch.get_num_threads()} thread(s)")
    print("| neurons | one block s | column blocks s | one / blocks | same run |")
    print("|---:|---:|---:|---:|---|")
    for neurons in (int(n) for n in args.neurons.split(",")):
        weights = (rng.random((INPUTS, neurons)) * 0.02).astype(np.float32)
        theta = np.full(neurons, 1.0, dtype=np.float32)
        float_run(spikes[:2], weights, theta, beta=0.9)  # compiled before the timings
        whole, one = timed(spikes, weights, theta, 1 << 30, args.repeats)  # a tile never cut: one block
        blocked, cut = timed(spikes, weights, theta, parallel.TILE_NEURONS, args.repeats)
        same = all(
            torch.equal(getattr(one, field), getattr(cut, field))
            for field in ("counts", "candidates_per_step", "final_voltage")
        )
        print(f"| {neurons:,} | {whole:.2f} | {blocked:.2f} | {whole / blocked:.2f} | {'yes' if same else 'NO'} |")


if __name__ == "__main__":
    main()
