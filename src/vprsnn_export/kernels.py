"""Compiled, event-driven step loops for inference: the float LIF+WTA network and the integer simulator.

The input is sparse (about 98 of 784 inputs spike per step), so instead of a dense
matmul each step sums only the weight rows of the inputs that spiked, and the whole
recurrence over presentations, steps and neurons runs in one numba-compiled loop
(no Python call per step). The step equations are those of :mod:`vprsnn_export.dynamics`
(float) and of ``targets/intsim.py`` / ``export/model.py`` (integer):

    float:    I_j = sum_{i active} w_ij                     (rows summed in increasing i)
              V_j = beta V_j + I_j;  C = {j : V_j > theta_j}
    integer:  A_j = sum_{i active} (q_ij << shift)          (exact)
              V_j = min((V_j keep) >> 12 + A_j, limit)      (clips counted)
              C = {j : V_j > theta_j << shift}
    WTA on:   the first j in C maximising I_j (float) or A_j m_j (integer) spikes
    WTA off:  every j in C spikes
    V_j <- 0 for every j in C

State is zeroed at the start of every presentation (isolation) or carried over in
order. The integer kernel is bit-identical to the integer simulator. The float kernel
sums each step's active rows in float32 in the order this machine's BLAS uses for the
dense matmul (probed: :func:`blas_block`), so it reproduces
:func:`vprsnn_export.dynamics.run_network` bit for bit where the probe succeeds; elsewhere
a current may differ in its last bit and, rarely, a threshold decision with it.
:func:`stdp_window` is the training window (WTA step, traces, STDP, clip, column
normalisation) with every float32 operation in the torch loop's order.

:func:`stdp_windows` runs that window for M independent modules of an ensemble in one call.

Compilation is lazy (first call, about a second per signature) and cached next to this
file (numba ``cache=True``); on a read-only install without a writable cache directory the
kernels are compiled in memory with one warning (:func:`compiled`). Each kernel call is
serial and releases the GIL: ``threads`` > 1 runs parts of a call (contiguous slices of
modules; whole WTA groups of neurons or presentations, :func:`run_parts`) on a pool of Python
threads. numba's threading layer is never launched (once launched, its OpenMP workers slowed
torch's training loop sevenfold here). Inference runs the neurons in tiles of whole WTA groups
(:func:`neuron_tile`): a tile's weights, copied contiguous, stay in cache across presentations.
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar, cast

import numpy as np
import torch
from numba import njit

from .config import Config
from .errors import InvalidValueError
from .kernel_checks import require_array, require_groups, require_int
from .runs import SpikeRun
from .widths import DECAY_BITS

INT32_SAFE = (1 << 31) - 1
QUERY_CHUNK = 128  # presentations run_network multiplies at once: bounds its (chunk, T, neurons) currents


F = TypeVar("F", bound=Callable[..., object])
_uncached: list[str] = []


def compiled(function: F) -> F:
    """numba ``njit(nogil=True, error_model="numpy")``, cached on disk when a cache directory is writable.

    numpy's error model: no Python zero-divisor check per division (the kernels never divide by
    zero), so divisions in loops vectorise; the results of every other division are the same.

    numba caches next to this file, else in the user's cache directory (or ``NUMBA_CACHE_DIR``);
    when none is writable (a read-only install and home) numba refuses ``cache=True`` at import,
    so the kernels are compiled in memory on first call instead, with one warning.
    """
    try:
        return cast(F, njit(cache=True, nogil=True, error_model="numpy")(function))
    except RuntimeError as exc:
        if not _uncached:
            warnings.warn(f"numba cannot cache the kernels ({exc}); compiling them in memory", stacklevel=2)
        _uncached.append(function.__name__)
        return cast(F, njit(nogil=True, error_model="numpy")(function))


def as_spike_array(spikes: torch.Tensor | np.ndarray) -> np.ndarray:
    """Spikes (N, T, inputs) of 0/1 uint8 or bool as a C-contiguous uint8 numpy array (no copy when possible)."""
    array = spikes.detach().cpu().numpy() if isinstance(spikes, torch.Tensor) else np.asarray(spikes)
    if array.ndim != 3:
        raise InvalidValueError(f"spikes: expected shape (N, T, inputs), got {array.shape}")
    if array.dtype == np.bool_:
        array = array.view(np.uint8)
    if array.dtype != np.uint8:
        raise InvalidValueError(f"spikes: expected uint8 or bool, got {array.dtype}")
    return np.ascontiguousarray(array)


@compiled
def _active_inputs(row: np.ndarray, index: np.ndarray) -> int:
    """Write the indices i with row[i] != 0 into index[:k], in increasing order; return k (branch-free)."""
    k = 0
    for i in range(row.shape[0]):
        index[k] = i
        k += row[i] != 0
    return k


@compiled
def _step_lists(spikes: np.ndarray, index: np.ndarray, offsets: np.ndarray) -> None:
    """Spikes (T, inputs) as per-step lists: step t's active inputs are index[offsets[t]:offsets[t + 1]]."""
    k = 0
    for t in range(spikes.shape[0]):
        offsets[t] = k
        k += _active_inputs(spikes[t], index[k:])
    offsets[spikes.shape[0]] = k


@compiled
def _integer_kernel(
    spikes: np.ndarray,  # (N, T, inputs) uint8
    mantissas: np.ndarray,  # (inputs, neurons) q_ij, unsigned, in the narrowest integer dtype that holds them
    shift: int,
    threshold: np.ndarray,  # (neurons,) int64: theta << shift
    multipliers: np.ndarray,  # (neurons,) int64 m_j
    use_multipliers: bool,
    keep: int,
    limit: int,
    wta: bool,
    group: int,  # neurons per WTA group (one module of an ensemble)
    isolation: bool,
    record: bool,
    current_store: np.ndarray,  # (T tile,) scratch: int32 when every sum of q fits, else int64
    start: int,  # the neurons [start, stop) this call runs: whole WTA groups
    stop: int,
    tile: int,  # neurons per tile: whole WTA groups
    counts: np.ndarray,  # (N, neurons) int64, written for [start, stop)
    n_candidates: np.ndarray,  # (N, T) int32, this call's candidates added
    raster: np.ndarray,  # (N or 0, T, neurons) bool
    final: np.ndarray,  # (N, neurons) int64
) -> tuple[int, np.int64]:
    """The integer network over the neurons [start, stop), tile by tile (as :func:`_float_kernel`).

    Returns (saturations, the largest shifted current) of these neurons.
    """
    n, timesteps, n_inputs = spikes.shape
    index, offsets = _all_step_lists(spikes)
    partial_store = np.empty(tile, dtype=current_store.dtype)
    tile_store = np.empty(n_inputs * tile, dtype=mantissas.dtype)
    saturations = 0
    peak = np.int64(0)
    for g0 in range(start, stop, tile):
        width = min(tile, stop - g0)
        current = current_store[: timesteps * width].reshape((timesteps, width))
        partial = partial_store[:width]
        tile_weights = tile_store[: n_inputs * width].reshape((n_inputs, width))  # contiguous rows
        for i in range(n_inputs):
            for jj in range(width):
                tile_weights[i, jj] = mantissas[i, g0 + jj]
        tile_threshold = threshold[g0 : g0 + width].copy()
        voltage = np.zeros(width, dtype=np.int64)
        candidate = np.zeros(width, dtype=np.bool_)
        for p in range(n):
            if isolation:
                voltage[:] = 0
            for t in range(timesteps):
                first, last = offsets[p, t], offsets[p, t + 1]
                _blocked_sum(tile_weights, index[first:last], last - first, n_inputs, current[t], partial)
            for t in range(timesteps):
                step = current[t]
                n_cand = 0
                for jj in range(width):  # branch-free: vectorised
                    c = np.int64(step[jj]) << shift
                    peak = max(peak, c)
                    v = ((voltage[jj] * keep) >> DECAY_BITS) + c
                    clipped = v > limit
                    saturations += clipped
                    v = limit if clipped else v
                    fire = v > tile_threshold[jj]
                    candidate[jj] = fire
                    voltage[jj] = 0 if fire else v
                    n_cand += fire
                n_candidates[p, t] += n_cand
                if n_cand > 0:
                    for g in range(0, width, group):
                        best = -1
                        best_score = np.int64(-1)
                        for jj in range(g, g + group):
                            if candidate[jj]:
                                j = g0 + jj
                                if not wta:
                                    counts[p, j] += 1
                                    if record:
                                        raster[p, t, j] = True
                                else:
                                    c = np.int64(step[jj]) << shift
                                    score = c * multipliers[j] if use_multipliers else c
                                    if score > best_score:
                                        best_score = score
                                        best = j
                        if best >= 0:
                            counts[p, best] += 1
                            if record:
                                raster[p, t, best] = True
            final[p, g0 : g0 + width] = voltage[:width]
    return saturations, peak


@compiled
def _blocked_sum(
    weights: np.ndarray,
    index: np.ndarray,
    k: int,
    block: int,
    total: np.ndarray,
    partial: np.ndarray,
) -> None:
    """total = sum over the active rows index[:k] of weights, the way a K-blocked GEMM adds them.

    Inputs are cut into blocks of ``block`` consecutive indices; each block's rows are summed
    from zero in increasing order, and the block sums are added to the total in order
    (``block`` >= the number of inputs: one plain left-to-right sum).
    """
    n = total.shape[0]
    if k == 0:
        for j in range(n):
            total[j] = 0
        return
    a = 0
    first = True
    while a < k:
        stop = (index[a] // block + 1) * block
        sums = total if first else partial  # the first block's sum from zero is the total so far
        row = weights[index[a]]
        for j in range(n):
            sums[j] = 0 + row[j]  # the block's sum from zero: 0 + w (as a zeroed sum adds it)
        a += 1
        while a < k and index[a] < stop:
            row = weights[index[a]]
            for j in range(n):
                sums[j] += row[j]
            a += 1
        if not first:
            for j in range(n):
                total[j] += partial[j]
        first = False


@compiled
def _blocked_currents(spikes: np.ndarray, weights: np.ndarray, block: int) -> np.ndarray:
    """Currents (rows, neurons) float32 of 0/1 spikes (rows, inputs) by :func:`_blocked_sum` (the BLAS probe)."""
    rows, n_inputs = spikes.shape
    out = np.empty((rows, weights.shape[1]), dtype=np.float32)
    index = np.empty(n_inputs, dtype=np.int64)
    partial = np.empty(weights.shape[1], dtype=np.float32)
    for r in range(rows):
        k = _active_inputs(spikes[r], index)
        _blocked_sum(weights, index, k, block, out[r], partial)
    return out


@compiled
def _float_kernel(
    spikes: np.ndarray,  # (N, T, inputs) uint8
    weights: np.ndarray,  # (inputs, neurons) float32
    theta: np.ndarray,  # (neurons,) float32
    beta: np.float32,
    wta: bool,
    group: int,  # neurons per WTA group (one module of an ensemble)
    isolation: bool,
    record: bool,
    block: int,
    start: int,  # the neurons [start, stop) this call runs: whole WTA groups
    stop: int,
    tile: int,  # neurons per tile: whole WTA groups
    counts: np.ndarray,  # (N, neurons) int64, written for [start, stop)
    n_candidates: np.ndarray,  # (N, T) int32, this call's candidates added
    raster: np.ndarray,  # (N or 0, T, neurons) bool
    final: np.ndarray,  # (N, neurons) float32
) -> None:
    """The float network over the neurons [start, stop), tile by tile: each tile's currents and
    state for every presentation before the next tile.

    Tiles hold whole WTA groups and groups never interact, so the order changes no number. A
    tile's weights are copied into contiguous rows (they stay in cache across presentations); the
    state update runs branch-free over the tile (vectorised), the WTA only on steps with candidates.
    (Summing the currents of a chunk of presentations in column blocks that fit in L2 measured slower.)
    """
    n, timesteps, n_inputs = spikes.shape
    index, offsets = _all_step_lists(spikes)
    zero = np.float32(0)
    lowest = np.float32(-np.inf)
    lane_value = np.empty(LANES, dtype=np.float32)
    lane_index = np.empty(LANES, dtype=np.int64)
    current_store = np.empty(timesteps * tile, dtype=np.float32)
    partial_store = np.empty(tile, dtype=np.float32)
    tile_store = np.empty(n_inputs * tile, dtype=np.float32)
    for g0 in range(start, stop, tile):
        width = min(tile, stop - g0)
        current = current_store[: timesteps * width].reshape((timesteps, width))
        partial = partial_store[:width]
        tile_weights = tile_store[: n_inputs * width].reshape((n_inputs, width))  # contiguous rows
        for i in range(n_inputs):
            for jj in range(width):
                tile_weights[i, jj] = weights[i, g0 + jj]
        tile_theta = theta[g0 : g0 + width].copy()
        voltage = np.zeros(width, dtype=np.float32)
        candidate = np.zeros(width, dtype=np.bool_)
        masked = np.empty(width, dtype=np.float32)  # I_j of the candidates, -inf elsewhere
        for p in range(n):
            if isolation:
                voltage[:] = 0
            for t in range(timesteps):
                first, last = offsets[p, t], offsets[p, t + 1]
                _blocked_sum(tile_weights, index[first:last], last - first, block, current[t], partial)
            for t in range(timesteps):
                step = current[t]
                n_cand = 0
                for jj in range(width):  # branch-free: vectorised
                    v = beta * voltage[jj] + step[jj]
                    fire = v > tile_theta[jj]
                    candidate[jj] = fire
                    masked[jj] = step[jj] if fire else lowest
                    voltage[jj] = zero if fire else v
                    n_cand += fire
                n_candidates[p, t] += n_cand
                if n_cand > 0 and wta:
                    for g in range(0, width, group):
                        best = _first_argmax(masked, g, g + group, lane_value, lane_index)
                        if best >= 0:
                            counts[p, g0 + best] += 1
                            if record:
                                raster[p, t, g0 + best] = True
                elif n_cand > 0:
                    for jj in range(width):
                        if candidate[jj]:
                            counts[p, g0 + jj] += 1
                            if record:
                                raster[p, t, g0 + jj] = True
            final[p, g0 : g0 + width] = voltage[:width]


LANES = 16  # independent running maxima of _first_argmax (one AVX-512 register of float32)


@compiled
def _first_argmax(values: np.ndarray, start: int, stop: int, lane_value: np.ndarray, lane_index: np.ndarray) -> int:
    """The first j in [start, stop) with the largest values[j] > -inf, or -1: the WTA winner, branch-free.

    Lane l keeps the first maximum among j = start + l (mod LANES) (strictly greater replaces);
    the lanes' largest value with its smallest index is the first maximum of the whole range,
    and the tail (indices above every lane's) replaces it only when strictly greater.
    """
    lowest = np.float32(-np.inf)
    for lane in range(LANES):
        lane_value[lane] = lowest
        lane_index[lane] = -1
    j = start
    while j + LANES <= stop:
        for lane in range(LANES):
            x = values[j + lane]
            better = x > lane_value[lane]
            lane_value[lane] = x if better else lane_value[lane]
            lane_index[lane] = j + lane if better else lane_index[lane]
        j += LANES
    best = -1
    best_value = lowest
    for lane in range(LANES):
        if lane_index[lane] >= 0 and (
            best < 0 or lane_value[lane] > best_value or (lane_value[lane] == best_value and lane_index[lane] < best)
        ):
            best_value = lane_value[lane]
            best = lane_index[lane]
    for k in range(j, stop):
        if values[k] > best_value:
            best_value = values[k]
            best = k
    return best


@compiled
def _all_step_lists(spikes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every presentation's per-step lists: step (p, t)'s active inputs are index[offsets[p, t]:offsets[p, t + 1]]."""
    n, timesteps, n_inputs = spikes.shape
    total = 0
    for p in range(n):
        for t in range(timesteps):
            for i in range(n_inputs):
                total += spikes[p, t, i] != 0
    index = np.empty(total + 1, dtype=np.int32)
    offsets = np.empty((n, timesteps + 1), dtype=np.int64)
    k = 0
    for p in range(n):
        _step_lists(spikes[p], index[k:], offsets[p])
        for t in range(timesteps + 1):
            offsets[p, t] += k
        k = offsets[p, timesteps]
    return index, offsets


TILE_NEURONS = 400  # neurons per tile of the kernels: one module of the default size
L2_WEIGHT_BYTES = (
    640 * 1024
)  # the float kernel sums currents in column blocks whose weights fit in this (1 MiB L2 here)
PRESENTATION_CHUNK = 16  # presentations whose currents the float kernel sums per column block before their steps


def neuron_tile(n_neurons: int, group: int) -> int:
    """Whole WTA groups, about :data:`TILE_NEURONS` neurons (at least one group, at most all)."""
    return min(n_neurons, group * max(1, TILE_NEURONS // group))


def run_parts(
    n_presentations: int, n_neurons: int, group: int, threads: int, isolation: bool
) -> list[tuple[slice, int, int]]:
    """How ``threads`` threads share a run: (presentations, start, stop) per thread.

    Neurons in whole WTA groups when there are enough groups (any isolation), else presentations
    (state isolation only: otherwise presentations are one stream and run in order).
    """
    groups = n_neurons // group
    if threads > 1 and groups >= threads:
        cuts = np.linspace(0, groups, threads + 1).round().astype(np.int64) * group
        return [(slice(0, n_presentations), int(a), int(b)) for a, b in zip(cuts[:-1], cuts[1:], strict=True) if b > a]
    if threads > 1 and isolation and n_presentations > 1:
        cuts = np.linspace(0, n_presentations, min(threads, n_presentations) + 1).round().astype(np.int64)
        return [(slice(int(a), int(b)), 0, n_neurons) for a, b in zip(cuts[:-1], cuts[1:], strict=True) if b > a]
    return [(slice(0, n_presentations), 0, n_neurons)]


def run_threads(tasks: Sequence[Callable[[], object]]) -> None:
    """Run the (GIL-releasing) tasks, on a pool of Python threads when there are several."""
    if len(tasks) == 1:
        tasks[0]()
        return
    with ThreadPoolExecutor(max_workers=len(tasks)) as pool:
        for future in [pool.submit(task) for task in tasks]:
            future.result()


def check_group(n_neurons: int, group: int | None) -> int:
    """The WTA group size: ``n_neurons`` for ``None``; ValueError unless it divides ``n_neurons``."""
    size = n_neurons if group is None else int(group)
    if size < 1 or n_neurons % size:
        raise InvalidValueError(f"group: WTA groups of {size} neurons do not divide {n_neurons} neurons")
    return size


def integer_run(
    spikes: torch.Tensor | np.ndarray,
    mantissas: np.ndarray,
    threshold: np.ndarray,
    multipliers: np.ndarray | None,
    *,
    shift: int,
    keep: int,
    limit: int,
    wta: bool,
    isolation: bool = True,
    record: bool = False,
    group: int | None = None,
    threads: int | None = None,
) -> SpikeRun:
    """The integer simulator's run, event-driven and compiled; bit-identical to ``targets.intsim.run_prepared``.

    ``group``: neurons per WTA group (:mod:`vprsnn_export.modules`); ``None``: one group.
    ``threads`` and the tiles of neurons as in :func:`float_run`.

    ``mantissas`` are the unshifted weights q_ij (inputs, neurons), non-negative; the kernel sums
    them in the narrowest dtype that holds them (uint8 for up to 8 bits: a quarter of the memory
    traffic of float32) and shifts each current by ``shift``: (sum q) << s == sum (q << s).
    ``threshold`` is theta_j << shift, ``multipliers`` the m_j (``None`` when all equal: the WTA
    then compares a_j), ``keep`` = 4096 - dv, ``limit`` the largest voltage. ``max_current`` is
    reported unshifted, as the simulator does.
    """
    array = as_spike_array(spikes)
    q = np.asarray(mantissas)
    if q.ndim != 2 or array.shape[2] != q.shape[0]:
        raise InvalidValueError(f"mantissas: spikes {array.shape} do not match weights {q.shape}")
    if q.size and int(q.min()) < 0:
        raise InvalidValueError("mantissas: integer weights must be non-negative (the kernel relies on V >= 0)")
    top = int(q.max()) if q.size else 0
    bound = int(q.astype(np.int64).sum(axis=0).max()) if q.size else 0
    if (bound << shift) >= (1 << 62):
        raise InvalidValueError(f"shift: current sums up to {bound} << {shift} overflow 64-bit voltages")
    storage = np.uint8 if top < (1 << 8) else np.uint16 if top < (1 << 16) else np.int64
    n, timesteps, _ = array.shape
    n_neurons = q.shape[1]
    size = check_group(n_neurons, group)
    weights = np.ascontiguousarray(q, dtype=storage)
    thresholds = np.ascontiguousarray(threshold, dtype=np.int64)
    scores = np.ones(n_neurons, dtype=np.int64) if multipliers is None else np.ascontiguousarray(multipliers, np.int64)
    counts = np.zeros((n, n_neurons), dtype=np.int64)
    raster = np.zeros((n if record else 0, timesteps, n_neurons), dtype=np.bool_)
    final = np.zeros((n, n_neurons), dtype=np.int64)
    tile = neuron_tile(n_neurons, size)
    parts = run_parts(n, n_neurons, size, torch.get_num_threads() if threads is None else threads, isolation)
    candidates = [np.zeros((len(range(n)[rows]), timesteps), dtype=np.int32) for rows, _, _ in parts]
    extremes: list[tuple[int, int]] = [(0, 0)] * len(parts)

    def task(k: int) -> Callable[[], None]:
        rows, start, stop = parts[k]

        def run() -> None:
            saturations, peak = integer_kernel(
                array[rows],
                weights,
                int(shift),
                thresholds,
                scores,
                multipliers is not None,
                int(keep),
                int(limit),
                bool(wta),
                size,
                bool(isolation),
                bool(record),
                np.zeros(timesteps * tile, dtype=np.int32 if bound <= INT32_SAFE else np.int64),
                start,
                stop,
                tile,
                counts[rows],
                candidates[k],
                raster[rows] if record else raster,
                final[rows],
            )
            extremes[k] = (int(saturations), int(peak))

        return run

    run_threads([task(k) for k in range(len(parts))])
    n_candidates = np.zeros((n, timesteps), dtype=np.int32)
    for (rows, _, _), part in zip(parts, candidates, strict=True):
        n_candidates[rows] += part
    return SpikeRun(
        counts=torch.from_numpy(counts),
        candidates_per_step=torch.from_numpy(n_candidates),
        raster=torch.from_numpy(raster) if record else None,
        final_voltage=torch.from_numpy(final),
        saturations=sum(e[0] for e in extremes),
        max_current=max(e[1] for e in extremes) >> shift,
    )


def float_run(
    spikes: torch.Tensor | np.ndarray,
    weights: torch.Tensor | np.ndarray,
    theta: torch.Tensor | np.ndarray,
    *,
    beta: float,
    wta: bool = True,
    isolation: bool = True,
    record: bool = False,
    block: int | None = None,
    group: int | None = None,
    threads: int | None = None,
) -> SpikeRun:
    """The float network's run (plasticity off), event-driven and compiled, on the CPU.

    ``group``: neurons per WTA group (:mod:`vprsnn_export.modules`); ``None``: one group.
    ``threads`` (default: torch's thread count): Python threads sharing the run, by whole WTA
    groups of neurons (an ensemble) or by presentations (:func:`run_parts`); the kernel runs
    the neurons in tiles of whole groups (:func:`neuron_tile`) so that a tile's weights stay
    in cache across the presentations.

    Same dynamics as :func:`vprsnn_export.dynamics.run_network`. Each step's currents are the
    active inputs' weight rows summed in float32 in blocks of ``block`` inputs (see
    :func:`_blocked_sum`); by default the block that reproduces this machine's BLAS on the
    shape ``run_network`` multiplies (:func:`blas_block`), so the counts are those of
    ``run_network`` bit for bit wherever the probe succeeds. ``final_voltage`` is reported
    with and without isolation.
    """
    array = as_spike_array(spikes)
    w = np.ascontiguousarray(_numpy(weights), dtype=np.float32)
    if w.ndim != 2 or array.shape[2] != w.shape[0]:
        raise InvalidValueError(f"weights: spikes {array.shape} do not match weights {w.shape}")
    n, timesteps, n_inputs = array.shape
    if block is None:
        block = blas_block(max(1, min(n, QUERY_CHUNK) * timesteps), n_inputs, w.shape[1]) or n_inputs
    n_neurons = w.shape[1]
    size = check_group(n_neurons, group)
    counts = np.zeros((n, n_neurons), dtype=np.int64)
    raster = np.zeros((n if record else 0, timesteps, n_neurons), dtype=np.bool_)
    final = np.zeros((n, n_neurons), dtype=np.float32)
    theta_array = np.ascontiguousarray(_numpy(theta), dtype=np.float32)
    parts = run_parts(n, n_neurons, size, torch.get_num_threads() if threads is None else threads, isolation)
    candidates = [np.zeros((len(range(n)[rows]), timesteps), dtype=np.int32) for rows, _, _ in parts]

    def task(k: int) -> Callable[[], None]:
        rows, start, stop = parts[k]
        return lambda: float_kernel(
            array[rows],
            w,
            theta_array,
            np.float32(beta),
            bool(wta),
            size,
            bool(isolation),
            bool(record),
            max(1, int(block)),
            start,
            stop,
            neuron_tile(n_neurons, size),
            counts[rows],
            candidates[k],
            raster[rows] if record else raster,
            final[rows],
        )

    run_threads([task(k) for k in range(len(parts))])
    n_candidates = np.zeros((n, timesteps), dtype=np.int32)
    for (rows, _, _), part in zip(parts, candidates, strict=True):
        n_candidates[rows] += part
    return SpikeRun(
        counts=torch.from_numpy(counts),
        candidates_per_step=torch.from_numpy(n_candidates),
        raster=torch.from_numpy(raster) if record else None,
        final_voltage=torch.from_numpy(final),
    )


BLOCK_CANDIDATES = (0, 192, 256, 128, 384, 512, 96, 64, 160, 224, 320, 448, 768)  # 0: no blocking
PROBE_ROWS = 512  # at most this many rows in a probe matmul


@functools.lru_cache(maxsize=64)
def _probe_block(rows: int, n_inputs: int, n_neurons: int, threads: int) -> int | None:
    gen = np.random.default_rng(20240611)
    spikes = gen.random((rows, n_inputs)) < 0.125
    weights = gen.random((n_inputs, n_neurons)).astype(np.float32)
    expected = torch.matmul(torch.from_numpy(spikes.astype(np.float32)), torch.from_numpy(weights)).numpy()
    packed = spikes.astype(np.uint8)
    for block in BLOCK_CANDIDATES:
        size = block or n_inputs
        if block and block >= n_inputs:
            continue
        if np.array_equal(blocked_currents(packed, weights, max(size, 1)), expected):
            return size
    return None


def blas_block(rows: int, n_inputs: int, n_neurons: int) -> int | None:
    """The K-block of torch's CPU float32 matmul (rows, inputs) @ (inputs, neurons) for 0/1 rows, if any reproduces it.

    With 0/1 left operands every product is exact, so a BLAS result differs from a plain sum
    only in the order of the additions. MKL's AVX-512 sgemm (torch 2.13 CPU wheel) sums the
    inputs in blocks of 192 for 64 rows and more and left to right for one or two rows;
    other builds may differ. Probed once per shape and thread count on random data (at most
    ``PROBE_ROWS`` rows); ``None`` when no candidate block reproduces it bit for bit.
    """
    return _probe_block(max(1, min(rows, PROBE_ROWS)), n_inputs, n_neurons, torch.get_num_threads())


@functools.lru_cache(maxsize=64)
def _probe_batch_sums(batch: int, n_inputs: int, n_neurons: int, threads: int) -> bool:
    gen = np.random.default_rng(20240612)
    trace = torch.from_numpy(gen.random((batch, n_inputs)).astype(np.float32))
    spikes = torch.from_numpy((gen.random((batch, n_inputs)) < 0.3).astype(np.float32))
    post = torch.from_numpy((gen.random((batch, n_neurons)) < 0.3).astype(np.float32))
    post_trace = torch.from_numpy(gen.random((batch, n_neurons)).astype(np.float32))
    for left, right in ((trace, post), (spikes, post_trace)):
        expected = (left.transpose(0, 1) @ right).numpy()
        total = np.zeros_like(expected)
        for b in range(batch):
            total = total + left[b].numpy()[:, None] * right[b].numpy()[None, :]
        if not np.array_equal(total, expected):
            return False
    return True


def batch_sums_in_order(batch: int, n_inputs: int, n_neurons: int) -> bool:
    """Whether torch's x^T @ y over a batch (the STDP terms) sums the rows left to right on this machine."""
    return _probe_batch_sums(batch, n_inputs, n_neurons, torch.get_num_threads())


@compiled
def _stdp_window(
    spikes: np.ndarray,  # (B, T, inputs) uint8
    weights: np.ndarray,  # (inputs, neurons) float32, updated in place
    theta: np.ndarray,  # (neurons,) float32
    beta: np.float32,
    wta: bool,
    pre_keep: np.float32,
    post_keep: np.float32,
    a_plus: np.float32,
    a_minus: np.float32,
    w_max: np.float32,
    weight_norm: bool,
    block: int,
) -> np.ndarray:
    """The training window, each float32 operation in the torch loop's order, in one pass over W per step.

    dW_ij = A+ (w_max - w_ij) P_ij - A- w_ij D_ij with P_ij = sum_b x_bi S_bj and
    D_ij = sum_b s_bi y_bj (b in order). S_bj is 0 unless j fires now, so P is built only for this
    step's winners (their rows of pre traces summed in row order); s_bi is 0 unless input i is active
    in row b, so D is built only for the active inputs (their rows' post traces summed in row order;
    y_bj is exactly 0 until j has fired in row b, and adding an exact 0 changes no float). W is then
    updated row by row over all neurons (vectorised), with dW_ij = +0 (W unchanged) wherever P and D
    are 0. Column normalisation divides column j by its norm n_j; a column no row has fired into
    ("untraced") whose norm was exactly 1.0f ("settled") keeps its weights (the division is the
    identity) and is divided by 1.
    """
    batch, timesteps, n_inputs = spikes.shape
    n_neurons = weights.shape[1]
    zero = np.float32(0)
    one = np.float32(1)
    tiny = np.float32(np.finfo(np.float32).tiny)
    voltage = np.zeros((batch, n_neurons), dtype=np.float32)
    post_trace = np.zeros((batch, n_neurons), dtype=np.float32)
    pre_trace = np.zeros((batch, n_inputs), dtype=np.float32)
    current = np.empty((batch, n_neurons), dtype=np.float32)
    fired = np.zeros((batch, n_neurons), dtype=np.bool_)
    partial = np.empty(n_neurons, dtype=np.float32)
    index = np.empty((batch, n_inputs), dtype=np.int64)
    n_active = np.empty(batch, dtype=np.int64)
    row_traced = np.zeros(batch, dtype=np.bool_)  # some neuron has fired in row b (y_b != 0)
    traced = np.zeros(n_neurons, dtype=np.bool_)  # neuron j has fired in some row
    winners = np.empty((batch, n_neurons), dtype=np.int64)  # per row: the neurons firing this step
    n_winners = np.zeros(batch, dtype=np.int64)
    settled = np.zeros(n_neurons, dtype=np.bool_)  # column norm exactly 1.0f and column unchanged since
    win_slot = np.full(n_neurons, -1, dtype=np.int64)  # neuron -> its row of P^T this step
    win_cols = np.empty(n_neurons, dtype=np.int64)
    potentiation = np.empty((n_neurons, n_inputs), dtype=np.float32)  # P^T, one row per winning column
    input_slot = np.full(n_inputs, -1, dtype=np.int64)  # input -> its row of D this step
    inputs_used = np.empty(n_inputs, dtype=np.int64)
    depression = np.empty((n_inputs, n_neurons), dtype=np.float32)  # one row per active input
    p_row = np.zeros(n_neurons, dtype=np.float32)
    zero_row = np.zeros(n_neurons, dtype=np.float32)
    squares = np.empty(n_neurons, dtype=np.float32)
    scale = np.empty(n_neurons, dtype=np.float32)
    fired_total = np.zeros(n_neurons, dtype=np.float32)
    partials = np.empty((batch, n_neurons), dtype=np.float32)
    starts = np.empty(n_inputs + 1, dtype=np.int64)
    members = np.empty(batch * n_inputs, dtype=np.int64)
    ready = False  # this step's lists and currents were made while normalising the last step's weights
    for t in range(timesteps):
        if not ready:
            for b in range(batch):
                n_active[b] = _active_inputs(spikes[b, t], index[b])
                _blocked_sum(weights, index[b], n_active[b], block, current[b], partial)
        ready = False
        for b in range(batch):
            row_voltage, row_current, row_fired = voltage[b], current[b], fired[b]
            n_cand = 0
            for j in range(n_neurons):  # branch-free: vectorised
                v = beta * row_voltage[j] + row_current[j]
                candidate = v > theta[j]
                row_fired[j] = candidate
                row_voltage[j] = zero if candidate else v
                n_cand += candidate
            n_winners[b] = 0
            if n_cand > 0 and wta:  # the first candidate with the largest current fires
                best = -1
                best_current = np.float32(-np.inf)
                for j in range(n_neurons):
                    if row_fired[j]:
                        row_fired[j] = False
                        if best < 0 or row_current[j] > best_current:
                            best_current = row_current[j]
                            best = j
                row_fired[best] = True
                winners[b, 0] = best
                n_winners[b] = 1
            elif n_cand > 0:
                for j in range(n_neurons):
                    if row_fired[j]:
                        winners[b, n_winners[b]] = j
                        n_winners[b] += 1
        for b in range(batch):
            for i in range(n_inputs):
                pre_trace[b, i] = pre_trace[b, i] * pre_keep + np.float32(spikes[b, t, i])
            if n_winners[b] > 0 or row_traced[b]:  # y_bj = 0 keep + 0 = 0 in a row that has never fired
                for j in range(n_neurons):
                    post_trace[b, j] = post_trace[b, j] * post_keep + (one if fired[b, j] else zero)
            for w in range(n_winners[b]):
                j = winners[b, w]
                fired_total[j] += one
                traced[j] = True
                row_traced[b] = True
        n_win = 0
        for b in range(batch):
            for w in range(n_winners[b]):
                j = winners[b, w]
                if win_slot[j] < 0:
                    win_slot[j] = n_win
                    win_cols[n_win] = j
                    potentiation[n_win] = zero
                    n_win += 1
                sums = potentiation[win_slot[j]]
                trace = pre_trace[b]
                for i in range(n_inputs):
                    sums[i] += trace[i]
        n_used = 0
        for b in range(batch):
            if row_traced[b]:
                for a in range(n_active[b]):
                    i = index[b, a]
                    if input_slot[i] < 0:
                        input_slot[i] = n_used
                        inputs_used[n_used] = i
                        depression[n_used] = zero
                        n_used += 1
                    sums = depression[input_slot[i]]
                    trace = post_trace[b]
                    for j in range(n_neurons):
                        sums[j] += trace[j]
        n_columns = 0
        for j in range(n_neurons):
            if traced[j] or (weight_norm and not settled[j]):
                n_columns += 1
        if n_columns > 0:
            squares[:] = zero
            for i in range(n_inputs):
                for q in range(n_win):
                    p_row[win_cols[q]] = potentiation[q, i]
                d_row = depression[input_slot[i]] if input_slot[i] >= 0 else zero_row
                row = weights[i]
                for j in range(n_neurons):
                    w = row[j]
                    delta = a_plus * (w_max - w) * p_row[j] - a_minus * w * d_row[j]
                    w = min(max(w + delta, zero), w_max)
                    row[j] = w
                    squares[j] += w * w
                for q in range(n_win):
                    p_row[win_cols[q]] = zero
            if weight_norm:
                dividing = False
                for j in range(n_neurons):
                    scale[j] = one
                    if traced[j] or not settled[j]:
                        scale[j] = max(np.sqrt(squares[j]), tiny)
                        settled[j] = scale[j] == one
                        dividing = dividing or not settled[j]
                if dividing and t + 1 < timesteps:
                    _divide_and_sum(
                        weights, scale, spikes[:, t + 1], index, n_active, block, current, partials, starts, members
                    )
                    ready = True
                elif dividing:
                    for i in range(n_inputs):
                        row = weights[i]
                        for j in range(n_neurons):
                            row[j] = row[j] / scale[j]
        for q in range(n_win):
            win_slot[win_cols[q]] = -1
        for u in range(n_used):
            input_slot[inputs_used[u]] = -1
    return fired_total


@compiled
def _divide_and_sum(
    weights: np.ndarray,  # (inputs, neurons) float32: divided by scale in place
    scale: np.ndarray,  # (neurons,) float32
    spikes: np.ndarray,  # (B, inputs) the next step's input spikes
    index: np.ndarray,  # (B, inputs) out: the next step's active inputs per row
    n_active: np.ndarray,  # (B,) out
    block: int,
    current: np.ndarray,  # (B, neurons) out: the next step's currents, as _blocked_sum sums them
    partials: np.ndarray,  # (B, neurons) scratch
    starts: np.ndarray,  # (inputs + 1,) scratch
    members: np.ndarray,  # (B inputs,) scratch
) -> None:
    """Column normalisation w_ij <- w_ij / n_j fused with the next step's currents, in one pass over W.

    Each row of W, once divided, is added (still in L1) to the currents of the rows b whose input
    is active next: row b's inputs arrive in increasing order, its first block summed into the
    total from zero and every later block from zero into a partial added to the total when the
    block ends, exactly the additions of :func:`_blocked_sum`.
    """
    batch, n_inputs = spikes.shape
    n = weights.shape[1]
    starts[:] = 0
    for b in range(batch):
        n_active[b] = _active_inputs(spikes[b], index[b])
        for a in range(n_active[b]):
            starts[index[b, a] + 1] += 1
    for i in range(n_inputs):
        starts[i + 1] += starts[i]
    for b in range(batch):  # rows of each input, increasing (starts[i] is the cursor, restored below)
        for a in range(n_active[b]):
            i = index[b, a]
            members[starts[i]] = b
            starts[i] += 1
    for i in range(n_inputs - 1, 0, -1):
        starts[i] = starts[i - 1]
    starts[0] = 0
    open_block = np.full(batch, -1, dtype=np.int64)  # per row: the block being summed (-1: none yet)
    into_total = np.ones(batch, dtype=np.bool_)  # the open block is the row's first: summed into the total
    for i in range(n_inputs):
        row = weights[i]
        for j in range(n):
            row[j] = row[j] / scale[j]
        here = i // block
        for m in range(starts[i], starts[i + 1]):
            b = members[m]
            if open_block[b] == here:
                sums = current[b] if into_total[b] else partials[b]
                for j in range(n):
                    sums[j] += row[j]
                continue
            if open_block[b] >= 0:  # a later block starts: the last one ends
                if not into_total[b]:
                    total = current[b]
                    part = partials[b]
                    for j in range(n):
                        total[j] += part[j]
                into_total[b] = False
            open_block[b] = here
            sums = current[b] if into_total[b] else partials[b]
            for j in range(n):
                sums[j] = 0 + row[j]
    for b in range(batch):
        total = current[b]
        if open_block[b] < 0:
            for j in range(n):
                total[j] = 0
        elif not into_total[b]:
            part = partials[b]
            for j in range(n):
                total[j] += part[j]


def stdp_window(
    weights: torch.Tensor, theta: torch.Tensor, spikes: torch.Tensor, cfg: Config
) -> tuple[torch.Tensor, torch.Tensor] | None:
    """One training batch (B, T, inputs) with plasticity on, compiled: the step loop of ``train.train_batch``.

    Per step: the WTA step, trace decay, STDP (eq. 7, summed over the batch in row order), clip
    and column normalisation, each float32 operation in torch's order, so the weights are bit
    for bit those of the torch loop when this machine's BLAS orders its sums as probed
    (:func:`blas_block`, :func:`batch_sums_in_order`). Returns (new weights, spikes per neuron
    in the batch as float32), or ``None`` when the tensors are not float32 on the CPU or the
    BLAS order is not reproducible: the caller then runs the torch loop. Homeostasis is the caller's.
    """
    batch, _, n_inputs = spikes.shape
    n_neurons = weights.shape[1]
    if weights.device.type != "cpu" or weights.dtype != torch.float32 or theta.dtype != torch.float32:
        return None
    block = blas_block(batch, n_inputs, n_neurons)
    if block is None or not batch_sums_in_order(batch, n_inputs, n_neurons):
        return None
    updated = weights.detach().clone().contiguous()
    fired = stdp_window_kernel(
        as_spike_array(spikes),
        updated.numpy(),
        np.ascontiguousarray(theta.detach().numpy()),
        np.float32(cfg.network.beta),
        bool(cfg.network.wta),
        np.float32(1.0 - 1.0 / cfg.stdp.tau_pre),
        np.float32(1.0 - 1.0 / cfg.stdp.tau_post),
        np.float32(cfg.stdp.a_plus),
        np.float32(cfg.stdp.a_minus),
        np.float32(cfg.stdp.w_max),
        bool(cfg.stdp.weight_norm),
        block,
    )
    return updated, torch.from_numpy(fired)


def _numpy(values: torch.Tensor | np.ndarray) -> np.ndarray:
    return values.detach().cpu().numpy() if isinstance(values, torch.Tensor) else np.asarray(values)


MT_N = 624  # words of the Mersenne Twister state (torch's CPU generator is MT19937)
MT_M = 397
MANTISSA_BITS = 24  # torch.rand(float32) keeps the low 24 bits of one 32-bit draw: u = (r & (2^24 - 1)) / 2^24


@compiled
def _mt_seed(seed: int, state: np.ndarray) -> None:
    """torch's ``mt19937(seed)``: x_0 = seed mod 2^32, x_j = 1812433253 (x_{j-1} ^ (x_{j-1} >> 30)) + j mod 2^32."""
    state[0] = np.uint32(seed & 0xFFFFFFFF)
    for j in range(1, MT_N):
        prev = np.uint64(state[j - 1])
        mixed = np.uint64(1812433253) * (prev ^ (prev >> np.uint64(30))) + np.uint64(j)
        state[j] = np.uint32(mixed & np.uint64(0xFFFFFFFF))


@compiled
def _mt_mantissas(state: np.ndarray, out: np.ndarray) -> None:
    """The next 624 draws of MT19937 (twist, then tempering), each reduced to its low 24 bits, into out[:624]."""
    upper = np.uint32(0x80000000)
    lower = np.uint32(0x7FFFFFFF)
    matrix = np.uint32(0x9908B0DF)
    one = np.uint32(1)
    for j in range(MT_N - MT_M):
        y = (state[j] & upper) | (state[j + 1] & lower)
        state[j] = state[j + MT_M] ^ (y >> one) ^ (matrix * (y & one))
    for j in range(MT_N - MT_M, MT_N - 1):
        y = (state[j] & upper) | (state[j + 1] & lower)
        state[j] = state[j + MT_M - MT_N] ^ (y >> one) ^ (matrix * (y & one))
    y = (state[MT_N - 1] & upper) | (state[0] & lower)
    state[MT_N - 1] = state[MT_M - 1] ^ (y >> one) ^ (matrix * (y & one))
    for j in range(MT_N):
        y = state[j]
        y ^= y >> np.uint32(11)
        y ^= (y << np.uint32(7)) & np.uint32(0x9D2C5680)
        y ^= (y << np.uint32(15)) & np.uint32(0xEFC60000)
        y ^= y >> np.uint32(18)
        out[j] = np.int32(y & np.uint32(0xFFFFFF))


@compiled
def _bernoulli_kernel(thresholds: np.ndarray, seeds: np.ndarray, timesteps: int, out: np.ndarray) -> None:
    """out[n, t, i] = m_n[t D + i] < thresholds[n, i], m_n the 24-bit draws of MT19937 seeded with seeds[n]."""
    n_rows, n_inputs = thresholds.shape
    total = timesteps * n_inputs
    state = np.empty(MT_N, dtype=np.uint32)
    draws = np.empty(total + MT_N, dtype=np.int32)
    for r in range(n_rows):
        _mt_seed(seeds[r], state)
        for start in range(0, total, MT_N):
            _mt_mantissas(state, draws[start : start + MT_N])
        limit = thresholds[r]
        for t in range(timesteps):
            row = draws[t * n_inputs : (t + 1) * n_inputs]
            target = out[r, t]
            for i in range(n_inputs):
                target[i] = row[i] < limit[i]


def bernoulli_spikes(prob: np.ndarray, seeds: Sequence[int], timesteps: int) -> np.ndarray:
    """Spikes (N, T, D) uint8 with s[n, t, i] = u[n, t, i] < p[n, i], u drawn as ``torch.rand`` draws them.

    Bit for bit ``torch.rand((T, D), generator=torch.Generator().manual_seed(seeds[n])) < p[n]``
    (about 13x faster): torch's CPU generator is MT19937 seeded with the seed's low 32 bits, and a
    float32 uniform is u = m / 2^24 with m the low 24 bits of one 32-bit draw. So u < p iff
    m < ceil(p 2^24), an integer comparison (p in [0, 1]; NaN never fires, as u < NaN is false).
    """
    p = np.asarray(prob, dtype=np.float32)
    if p.ndim != 2 or len(seeds) != p.shape[0]:
        raise InvalidValueError(f"prob: expected (N, D) probabilities and N seeds, got {p.shape} and {len(seeds)}")
    limits = bernoulli_limits(p)
    out = np.empty((p.shape[0], int(timesteps), p.shape[1]), dtype=np.uint8)
    bernoulli_kernel(limits, generator_seeds(seeds), int(timesteps), out)
    return out


def bernoulli_limits(prob: np.ndarray) -> np.ndarray:
    """The integer thresholds ceil(p 2^24), clipped to [0, 2^24], int32: u < p iff m < ceil(p 2^24) (NaN: 0)."""
    p = np.asarray(prob, dtype=np.float32)
    scaled = np.ceil(np.nan_to_num(p.astype(np.float64), nan=0.0) * float(1 << MANTISSA_BITS))
    return np.ascontiguousarray(np.clip(scaled, 0, 1 << MANTISSA_BITS), dtype=np.int32)


def generator_seeds(seeds: Sequence[int]) -> np.ndarray:
    """The seeds as torch's CPU generator uses them: their low 32 bits, int64."""
    return np.array([int(s) & 0xFFFFFFFF for s in seeds], dtype=np.int64)


@compiled
def _stdp_windows(
    limits: np.ndarray,  # (M, B, inputs) int32: bernoulli_limits of each row's firing probabilities
    seeds: np.ndarray,  # (M, B) int64: generator_seeds of each row's presentation seed
    sizes: np.ndarray,  # (M,) int64: rows of module m in this batch (0: it sits the batch out)
    blocks: np.ndarray,  # (M,) int64: the K-block of each module's current sums (blas_block of its rows)
    timesteps: int,
    weights: np.ndarray,  # (M, inputs, neurons) float32, updated in place
    theta: np.ndarray,  # (M, neurons) float32
    beta: np.float32,
    wta: bool,
    pre_keep: np.float32,
    post_keep: np.float32,
    a_plus: np.float32,
    a_minus: np.float32,
    w_max: np.float32,
    weight_norm: bool,
) -> np.ndarray:
    """One training batch of every module: encode module m's rows, then its :func:`_stdp_window`.

    The modules are independent networks, so each one's window is exactly the single network's;
    returns the spikes per neuron of every module in this batch (M, neurons) float32.
    """
    n_modules, batch, n_inputs = limits.shape
    fired = np.zeros((n_modules, weights.shape[2]), dtype=np.float32)
    spikes = np.empty((batch, timesteps, n_inputs), dtype=np.uint8)
    for m in range(n_modules):
        rows = sizes[m]
        if rows > 0:
            _bernoulli_kernel(limits[m, :rows], seeds[m, :rows], timesteps, spikes[:rows])
            fired[m] = _stdp_window(
                spikes[:rows],
                weights[m],
                theta[m],
                beta,
                wta,
                pre_keep,
                post_keep,
                a_plus,
                a_minus,
                w_max,
                weight_norm,
                blocks[m],
            )
    return fired


# The checked entry points: every compiled kernel is called from Python only through these,
# which refuse any array the kernel would index out of bounds (numba checks no bounds).
SPIKES = (np.uint8,)
ANY3 = (None, None, None)


def integer_kernel(
    spikes: np.ndarray,
    mantissas: np.ndarray,
    shift: int,
    threshold: np.ndarray,
    multipliers: np.ndarray,
    use_multipliers: bool,
    keep: int,
    limit: int,
    wta: bool,
    group: int,
    isolation: bool,
    record: bool,
    current_store: np.ndarray,
    start: int,
    stop: int,
    tile: int,
    counts: np.ndarray,
    n_candidates: np.ndarray,
    raster: np.ndarray,
    final: np.ndarray,
) -> tuple[int, np.int64]:
    """:func:`_integer_kernel` once every array it indexes is checked (InvalidValueError naming it)."""
    k = "integer kernel"
    require_array(k, "spikes", spikes, SPIKES, ANY3)
    n, timesteps, n_inputs = spikes.shape
    require_array(k, "mantissas", mantissas, (np.uint8, np.uint16, np.int64), (n_inputs, None))
    n_neurons = mantissas.shape[1]
    require_array(k, "threshold", threshold, (np.int64,), (n_neurons,))
    require_array(k, "multipliers", multipliers, (np.int64,), (n_neurons,))
    require_groups(k, n_neurons, group, start, stop, tile)
    require_int(k, "shift", shift, 0, 62)
    require_array(k, "current_store", current_store, (np.int32, np.int64), (None,), writable=True)
    if current_store.shape[0] < timesteps * tile:
        raise InvalidValueError(f"{k}: current_store holds {current_store.shape[0]} values, needs {timesteps * tile}")
    require_array(k, "counts", counts, (np.int64,), (n, n_neurons), writable=True)
    require_array(k, "n_candidates", n_candidates, (np.int32,), (n, timesteps), writable=True)
    require_array(k, "raster", raster, (np.bool_,), (n if record else None, timesteps, n_neurons), writable=True)
    require_array(k, "final", final, (np.int64,), (n, n_neurons), writable=True)
    return _integer_kernel(
        spikes, mantissas, int(shift), threshold, multipliers, bool(use_multipliers), int(keep), int(limit),
        bool(wta), int(group), bool(isolation), bool(record), current_store, int(start), int(stop), int(tile),
        counts, n_candidates, raster, final,
    )  # fmt: skip


def float_kernel(
    spikes: np.ndarray,
    weights: np.ndarray,
    theta: np.ndarray,
    beta: np.float32,
    wta: bool,
    group: int,
    isolation: bool,
    record: bool,
    block: int,
    start: int,
    stop: int,
    tile: int,
    counts: np.ndarray,
    n_candidates: np.ndarray,
    raster: np.ndarray,
    final: np.ndarray,
) -> None:
    """:func:`_float_kernel` once every array it indexes is checked (InvalidValueError naming it)."""
    k = "float kernel"
    require_array(k, "spikes", spikes, SPIKES, ANY3)
    n, timesteps, n_inputs = spikes.shape
    require_array(k, "weights", weights, (np.float32,), (n_inputs, None))
    n_neurons = weights.shape[1]
    require_array(k, "theta", theta, (np.float32,), (n_neurons,))
    require_groups(k, n_neurons, group, start, stop, tile)
    require_int(k, "block", block, 1)
    require_array(k, "counts", counts, (np.int64,), (n, n_neurons), writable=True)
    require_array(k, "n_candidates", n_candidates, (np.int32,), (n, timesteps), writable=True)
    require_array(k, "raster", raster, (np.bool_,), (n if record else None, timesteps, n_neurons), writable=True)
    require_array(k, "final", final, (np.float32,), (n, n_neurons), writable=True)
    _float_kernel(
        spikes, weights, theta, np.float32(beta), bool(wta), int(group), bool(isolation), bool(record), int(block),
        int(start), int(stop), int(tile), counts, n_candidates, raster, final,
    )  # fmt: skip


def blocked_currents(spikes: np.ndarray, weights: np.ndarray, block: int) -> np.ndarray:
    """:func:`_blocked_currents` once its arrays are checked (InvalidValueError naming them)."""
    k = "blocked currents"
    require_array(k, "spikes", spikes, SPIKES, (None, None))
    require_array(k, "weights", weights, (np.float32,), (spikes.shape[1], None))
    return _blocked_currents(spikes, weights, require_int(k, "block", block, 1))


def stdp_window_kernel(
    spikes: np.ndarray,
    weights: np.ndarray,
    theta: np.ndarray,
    beta: np.float32,
    wta: bool,
    pre_keep: np.float32,
    post_keep: np.float32,
    a_plus: np.float32,
    a_minus: np.float32,
    w_max: np.float32,
    weight_norm: bool,
    block: int,
) -> np.ndarray:
    """:func:`_stdp_window` once every array it indexes is checked (InvalidValueError naming it)."""
    k = "STDP window kernel"
    require_array(k, "spikes", spikes, SPIKES, ANY3)
    require_array(k, "weights", weights, (np.float32,), (spikes.shape[2], None), writable=True)
    require_array(k, "theta", theta, (np.float32,), (weights.shape[1],))
    require_int(k, "block", block, 1)
    return _stdp_window(
        spikes, weights, theta, beta, bool(wta), pre_keep, post_keep, a_plus, a_minus, w_max, bool(weight_norm),
        int(block),
    )  # fmt: skip


def bernoulli_kernel(thresholds: np.ndarray, seeds: np.ndarray, timesteps: int, out: np.ndarray) -> None:
    """:func:`_bernoulli_kernel` once its arrays are checked (InvalidValueError naming them)."""
    k = "Bernoulli kernel"
    require_array(k, "thresholds", thresholds, (np.int32,), (None, None))
    n_rows, n_inputs = thresholds.shape
    require_array(k, "seeds", seeds, (np.int64,), (n_rows,))
    steps = require_int(k, "timesteps", timesteps, 0)
    require_array(k, "out", out, SPIKES, (n_rows, steps, n_inputs), writable=True)
    _bernoulli_kernel(thresholds, seeds, steps, out)


def stdp_windows_kernel(
    limits: np.ndarray,
    seeds: np.ndarray,
    sizes: np.ndarray,
    blocks: np.ndarray,
    timesteps: int,
    weights: np.ndarray,
    theta: np.ndarray,
    *args: Any,
) -> np.ndarray:
    """:func:`_stdp_windows` once every array it indexes is checked (InvalidValueError naming it).

    ``args``: beta, wta, pre_keep, post_keep, a_plus, a_minus, w_max, weight_norm.
    """
    k = "STDP windows kernel"
    require_array(k, "limits", limits, (np.int32,), ANY3)
    n_modules, batch, n_inputs = limits.shape
    require_array(k, "seeds", seeds, (np.int64,), (n_modules, batch))
    require_array(k, "sizes", sizes, (np.int64,), (n_modules,))
    require_array(k, "blocks", blocks, (np.int64,), (n_modules,))
    if sizes.size and (sizes.min() < 0 or sizes.max() > batch):
        raise InvalidValueError(f"{k}: sizes must lie in [0, {batch}], got [{sizes.min()}, {sizes.max()}]")
    if (blocks[sizes > 0] < 1).any():
        raise InvalidValueError(f"{k}: blocks must be >= 1 for every module with a batch")
    steps = require_int(k, "timesteps", timesteps, 0)
    require_array(k, "weights", weights, (np.float32,), (n_modules, n_inputs, None), writable=True)
    require_array(k, "theta", theta, (np.float32,), (n_modules, weights.shape[2]))
    if len(args) != 8:
        raise InvalidValueError(f"{k}: expected 8 scalar parameters, got {len(args)}")
    return _stdp_windows(limits, seeds, sizes, blocks, steps, weights, theta, *args)


def module_slices(n_modules: int, parts: int) -> list[slice]:
    """At most ``parts`` contiguous, non-empty, nearly equal slices of range(n_modules)."""
    bounds = np.linspace(0, n_modules, max(1, min(parts, n_modules)) + 1).round().astype(int)
    return [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True) if b > a]


def stdp_windows(
    weights: np.ndarray,
    theta: np.ndarray,
    limits: np.ndarray,
    seeds: np.ndarray,
    sizes: np.ndarray,
    cfg: Config,
    *,
    threads: int = 1,
) -> np.ndarray | None:
    """One training batch of M independent modules, compiled: :func:`stdp_window` for each, side by side.

    ``weights`` (M, inputs, n) float32 C-contiguous are updated in place; ``theta`` (M, n) float32;
    module m's batch is its first ``sizes[m]`` rows of ``limits`` (M, B, inputs) int32
    (:func:`bernoulli_limits`) and ``seeds`` (M, B) (:func:`generator_seeds`), encoded inside the
    kernel exactly as :func:`bernoulli_spikes` encodes them, so module m's weights are those of
    ``stdp_window`` on its own batch bit for bit. ``threads`` > 1 runs contiguous slices of the
    modules in a pool of Python threads (the kernel releases the GIL; numba's threading layer is
    not used). Returns the spikes per neuron (M, n) float32, or ``None`` when this machine's BLAS
    order is not reproducible for some batch size (the caller then runs the torch loop).
    """
    n_modules, _, n_inputs = limits.shape
    n_neurons = weights.shape[2]
    blocks = np.zeros(n_modules, dtype=np.int64)
    for size in sorted({int(s) for s in sizes if s > 0}):
        block = blas_block(size, n_inputs, n_neurons)
        if block is None or not batch_sums_in_order(size, n_inputs, n_neurons):
            return None
        blocks[np.asarray(sizes) == size] = block
    args = (
        np.float32(cfg.network.beta),
        bool(cfg.network.wta),
        np.float32(1.0 - 1.0 / cfg.stdp.tau_pre),
        np.float32(1.0 - 1.0 / cfg.stdp.tau_post),
        np.float32(cfg.stdp.a_plus),
        np.float32(cfg.stdp.a_minus),
        np.float32(cfg.stdp.w_max),
        bool(cfg.stdp.weight_norm),
    )
    timesteps = int(cfg.encoder.timesteps)
    sizes = np.ascontiguousarray(sizes, dtype=np.int64)

    def run(part: slice) -> np.ndarray:
        return stdp_windows_kernel(
            limits[part], seeds[part], sizes[part], blocks[part], timesteps, weights[part], theta[part], *args
        )

    parts = module_slices(n_modules, threads)
    if len(parts) == 1:
        return run(parts[0])
    with ThreadPoolExecutor(max_workers=len(parts)) as pool:
        return np.concatenate(list(pool.map(run, parts)))
