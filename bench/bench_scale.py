"""The readout by route length: the whole-matrix readout against the one in query blocks, side by side.

On a lean-shaped route (one neuron per place, modules of 100: the ensemble's region regularisation on), with
synthetic calibration and query counts shaped like a trained route's (a neuron fires for 7 neighbouring places;
a query's spikes mostly on its place's neuron, one spike each on 24 others: an ensemble WTA has at most T
winners per query), stored sparse (CSR, as the readout keeps them), every place a query, W+Prob at
k = 1 / 5 / 10: seconds of each readout (best of ``--repeats``), the peak of numpy allocations during it
(tracemalloc), and whether the two give the same columns bit for bit. Where the whole matrices would not fit in
``--memory`` the row says what they would need and runs the blocks alone.

    python bench/bench_scale.py --threads 1 [--places 2400,10000,27000,100000] [--repeats 1] [--memory 12G]
"""

from __future__ import annotations

import argparse
import time
import tracemalloc

import numpy as np
from scipy import sparse

from vprsnn_export.config import preset
from vprsnn_export.data.truth import EXACT
from vprsnn_export.readout.scoring import READOUT_BLOCK, Readout
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.resources import parse_size
from vprsnn_export.threads import set_threads

KS = (1, 5, 10)
GIB = 2**30


def route_counts(places: int, rng: np.random.Generator) -> tuple[sparse.csr_array, sparse.csr_array]:
    """S^R (neurons x places) and query counts (places x neurons), CSR, of a lean route of ``places`` places."""
    neurons = places
    home = rng.integers(0, places, neurons)
    rows = np.repeat(np.arange(neurons), 7)
    cols = np.clip(home[:, None] + np.arange(-3, 4)[None, :], 0, places - 1).ravel()
    sr = sparse.csr_array((rng.poisson(4.0, len(rows)).astype(np.float64), (rows, cols)), shape=(neurons, places))
    favourite = np.argsort(home)[np.clip(np.arange(places) * neurons // places, 0, neurons - 1)]
    others = rng.integers(0, neurons, (places, 24))
    q_rows = np.repeat(np.arange(places), 25)
    q_cols = np.concatenate([favourite[:, None], others], axis=1).ravel()
    values = np.concatenate([rng.poisson(6.0, (places, 1)), np.ones((places, 24))], axis=1).ravel()
    counts = sparse.csr_array((values.astype(np.float64), (q_rows, q_cols)), shape=(places, neurons))
    return sr, counts


def measured(call):
    """(result, seconds, peak MiB of numpy allocations) of one call."""
    tracemalloc.start()
    began = time.perf_counter()
    result = call()
    seconds = time.perf_counter() - began
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    return result, seconds, peak


def whole_need(places: int) -> float:
    """GiB of the whole readout's matrices: 3 strategies at k=1 and the aggregates at each k > 1 (queries x places)."""
    return 8 * places * places * (3 + len(KS) - 1) / GIB


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--places", default="2400,10000,27000,100000")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--memory", default="12G", help="the most the whole-matrix readout may need")
    args = parser.parse_args()
    set_threads(args.threads)
    budget = parse_size(args.memory) / GIB
    cfg = preset("lean")
    print(f"threads {args.threads}; lean route shape (one neuron per place, modules of {cfg.train.module_size}); "
          f"k = {', '.join(map(str, KS))}; block {READOUT_BLOCK} queries")  # fmt: skip
    print(f"{'places':>7}  {'S^R MiB':>7}  {'whole s':>8}  {'whole MiB':>9}  {'blocks s':>8}  {'blocks MiB':>10}  "
          f"{'ratio s':>7}  same")  # fmt: skip
    for places in (int(p) for p in args.places.split(",")):
        rng = np.random.default_rng(places)
        sr, counts = route_counts(places, rng)
        stored = (sr.data.nbytes + sr.indices.nbytes + sr.indptr.nbytes) / 2**20
        ids = np.arange(places)
        readout = Readout.of(sr, cfg.replace(**{"network.n_neurons": cfg.train.module_size}), SequenceOptions(ks=KS))
        blocks = [measured(lambda: readout.score_in_blocks(counts, ids, ids, EXACT)) for _ in range(args.repeats)]
        scored, b_seconds, b_peak = min(blocks, key=lambda m: m[1])
        if whole_need(places) > budget:
            need = f"{whole_need(places) * 1024:.0f}*"
            print(f"{places:>7}  {stored:7.1f}  {'-':>8}  {need:>9}  {b_seconds:8.2f}  {b_peak:10.0f}  {'-':>7}  "
                  "(* would need; not run)")  # fmt: skip
            continue
        wholes = [measured(lambda: readout.score(counts, ids, ids, EXACT)) for _ in range(args.repeats)]
        whole, w_seconds, w_peak = min(wholes, key=lambda m: m[1])
        same = all(
            np.array_equal(a.index, b.index) and a.confidence.tobytes() == b.confidence.tobytes()
            for a, b in zip(whole.columns, scored.columns, strict=True)
        )
        print(f"{places:>7}  {stored:7.1f}  {w_seconds:8.2f}  {w_peak:9.0f}  {b_seconds:8.2f}  {b_peak:10.0f}  "
              f"{w_seconds / b_seconds:7.2f}  {same}")  # fmt: skip


if __name__ == "__main__":
    main()
