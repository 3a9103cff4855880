"""The kernels' ordered row sum (``kernel_sums._row_sum``) against the indexed loop it replaced, side by side.

Every compiled kernel (the float network, the integer simulator, the STDP window) sums each step's active weight
rows with ``_row_sum``. It used to read row ``r`` at ``r[offset + j]``: numba cannot prove that index non-negative,
so it keeps its wraparound check and the loop stays scalar. The rows are now sliced to the columns first and read
at ``r[j]``, j from 0: the loop vectorises. Both add the same rows in the same order, so every sum is the same
bit for bit (checked here in the same run). One step of the lean preset: about 50 of 1,568 inputs active; each
cell is the best of ``--repeats`` batches of ``--steps`` steps (fewer at many neurons: about 20 MB of currents),
one thread.

    python bench/bench_row_sum.py [--neurons 100,400,2400,27000] [--steps 2000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from vprsnn_export.network.kernel_sums import _row_sum, compiled
from vprsnn_export.threads import set_threads

INPUTS, ACTIVE = 1568, 50  # the lean preset: DoG ON/OFF 28 x 28, ~4,100 input spikes over T = 80 steps


@compiled
def indexed_row_sum(weights: np.ndarray, index: np.ndarray, k: int, total: np.ndarray, offset: int = 0) -> None:
    """The row sum as it was: each row read at ``offset + j`` (the baseline)."""
    n = total.shape[0]
    for j in range(n):
        total[j] = 0
    a = 0
    while a + 8 <= k:
        r0, r1, r2, r3 = weights[index[a]], weights[index[a + 1]], weights[index[a + 2]], weights[index[a + 3]]
        r4, r5, r6, r7 = weights[index[a + 4]], weights[index[a + 5]], weights[index[a + 6]], weights[index[a + 7]]
        for j in range(n):
            o = offset + j
            total[j] = (((((((total[j] + r0[o]) + r1[o]) + r2[o]) + r3[o]) + r4[o]) + r5[o]) + r6[o]) + r7[o]
        a += 8
    for b in range(a, k):
        row = weights[index[b]]
        for j in range(n):
            total[j] += row[offset + j]


@compiled
def steps(row_sum, weights: np.ndarray, index: np.ndarray, current: np.ndarray, offset: int) -> None:
    """``row_sum`` of every step's active rows (index[t]) into current[t] from column ``offset`` on (a run-time
    value, as in the kernels' column blocks), as the kernels call it."""
    for t in range(current.shape[0]):
        row_sum(weights, index[t], index.shape[1], current[t], offset)


def best_of(row_sum, weights: np.ndarray, index: np.ndarray, current: np.ndarray, repeats: int) -> float:
    steps(row_sum, weights, index[:1], current[:1], 0)  # compiled before timing
    best = float("inf")
    for _ in range(repeats):
        began = time.perf_counter()
        steps(row_sum, weights, index, current, 0)
        best = min(best, time.perf_counter() - began)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--neurons", default="100,400,2400,27000")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    set_threads(1)
    rng = np.random.default_rng(0)
    print(
        f"{'neurons':>8} {'indexed us/step':>16} {'sliced us/step':>15} {'ratio':>6} {'adds/ns sliced':>15}  same bits"
    )
    for n in (int(x) for x in args.neurons.split(",")):
        count = max(10, min(args.steps, 5_000_000 // n))  # steps: at most ~20 MB of currents
        weights = rng.random((INPUTS, n), dtype=np.float32)
        index = np.sort(np.argsort(rng.random((count, INPUTS)), axis=1)[:, :ACTIVE], axis=1).astype(np.int32)
        old, new = np.empty((count, n), np.float32), np.empty((count, n), np.float32)
        before = best_of(indexed_row_sum, weights, index, old, args.repeats) / count
        after = best_of(_row_sum, weights, index, new, args.repeats) / count
        print(
            f"{n:>8} {1e6 * before:>16.2f} {1e6 * after:>15.2f} {before / after:>6.1f} "
            f"{ACTIVE * n / after / 1e9:>15.1f}  {old.tobytes() == new.tobytes()}"
        )


if __name__ == "__main__":
    main()
