"""The float network's compiled, event-driven step loop (plasticity off): :func:`float_run`.

The step equations are those of :mod:`vprsnn_export.network.dynamics`:

    I_j = sum_{i active} w_ij                     (rows summed in increasing i)
    V_j = beta V_j + I_j;  C = {j : V_j > theta_j}
    WTA on:   the first j in C maximising I_j spikes
    WTA off:  every j in C spikes
    V_j <- 0 for every j in C

State is zeroed at the start of every presentation (isolation) or carried over in order. The
kernel sums each step's active rows in float32 in increasing input order, the same on every CPU
(:func:`vprsnn_export.network.kernel_sums._row_sum`); the torch loop of
:func:`vprsnn_export.network.dynamics.run_network` (GPU, ``compiled=False``) sums in its BLAS's order,
so a current may differ in its last bit and, rarely, a threshold decision with it. The neurons run in
tiles of whole WTA groups, on threads (:mod:`vprsnn_export.network.parallel`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from ..errors import InvalidValueError
from .kernel_checks import require_array, require_groups, require_int
from .kernel_sums import ANY3, SPIKES, _all_step_lists, _column_blocks, _numpy, _tile_currents, as_spike_array, compiled
from .parallel import check_group, current_blocks, neuron_tile, run_parts, run_threads
from .runs import SpikeRun

QUERY_CHUNK = 128  # presentations run_network multiplies at once: bounds its (chunk, T, neurons) currents


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
    start: int,  # the neurons [start, stop) this call runs: whole WTA groups
    stop: int,
    tile: int,  # neurons per tile: whole WTA groups
    column: int,  # neurons per column block of a tile's current sums
    chunk: int,  # presentations whose currents are summed before their steps
    counts: np.ndarray,  # (N, neurons) int64, written for [start, stop)
    n_candidates: np.ndarray,  # (N, T) int32, this call's candidates added
    raster: np.ndarray,  # (N or 0, T, neurons) bool
    final: np.ndarray,  # (N, neurons) float32
) -> None:
    """The float network over the neurons [start, stop), tile by tile: each tile's currents and
    state for every presentation before the next tile.

    Tiles hold whole WTA groups and groups never interact, so the order changes no number. A
    tile's weights are copied into contiguous column blocks of ``column`` neurons; the currents of ``chunk``
    presentations are summed block by block (a block's weights stay in cache across them), then their steps
    run: the state update branch-free over the tile (vectorised), the WTA only on steps with candidates.
    Each current is the same ordered sum over the same inputs whatever the blocks, so no number changes.
    """
    n, timesteps, n_inputs = spikes.shape
    index, offsets = _all_step_lists(spikes)
    zero = np.float32(0)
    lowest = np.float32(-np.inf)
    lane_value = np.empty(LANES, dtype=np.float32)
    lane_index = np.empty(LANES, dtype=np.int64)
    current_store = np.empty(chunk * timesteps * tile, dtype=np.float32)
    store = np.empty(n_inputs * tile if n > 1 else 0, dtype=np.float32)  # none for a lone presentation: in place
    for g0 in range(start, stop, tile):
        width = min(tile, stop - g0)
        current = current_store[: chunk * timesteps * width].reshape((chunk, timesteps, width))
        _column_blocks(weights, g0, width, column, store)
        tile_theta = theta[g0 : g0 + width].copy()
        voltage = np.zeros(width, dtype=np.float32)
        candidate = np.zeros(width, dtype=np.bool_)
        masked = np.empty(width, dtype=np.float32)  # I_j of the candidates, -inf elsewhere
        for p0 in range(0, n, chunk):
            p1 = min(n, p0 + chunk)
            _tile_currents(weights, store, g0, width, column, index, offsets, p0, p1, current)
            for p in range(p0, p1):
                if isolation:
                    voltage[:] = 0
                for t in range(timesteps):
                    step = current[p - p0, t]
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
    lane_value[:] = lowest
    lane_index[:] = -1
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


def float_kernel(
    spikes: np.ndarray,
    weights: np.ndarray,
    theta: np.ndarray,
    beta: np.float32,
    wta: bool,
    group: int,
    isolation: bool,
    record: bool,
    start: int,
    stop: int,
    tile: int,
    column: int,
    chunk: int,
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
    require_int(k, "column", column, 1)
    require_int(k, "chunk", chunk, 1)
    require_array(k, "counts", counts, (np.int64,), (n, n_neurons), writable=True)
    require_array(k, "n_candidates", n_candidates, (np.int32,), (n, timesteps), writable=True)
    require_array(k, "raster", raster, (np.bool_,), (n if record else None, timesteps, n_neurons), writable=True)
    require_array(k, "final", final, (np.float32,), (n, n_neurons), writable=True)
    _float_kernel(
        spikes, weights, theta, np.float32(beta), bool(wta), int(group), bool(isolation), bool(record),
        int(start), int(stop), int(tile), int(column), int(chunk), counts, n_candidates, raster, final,
    )  # fmt: skip


def float_run(
    spikes: torch.Tensor | np.ndarray,
    weights: torch.Tensor | np.ndarray,
    theta: torch.Tensor | np.ndarray,
    *,
    beta: float,
    wta: bool = True,
    isolation: bool = True,
    record: bool = False,
    group: int | None = None,
    threads: int | None = None,
) -> SpikeRun:
    """The float network's run (plasticity off), event-driven and compiled, on the CPU.

    ``group``: neurons per WTA group (:mod:`vprsnn_export.network.modules`); ``None``: one group.
    ``threads`` (default: torch's thread count): Python threads sharing the run, by whole WTA groups of neurons
    (an ensemble) or by presentations (:func:`run_parts`); the kernel runs the neurons in tiles of whole groups
    (:func:`neuron_tile`) so that a tile's weights stay in cache across the presentations.

    Same dynamics as :func:`vprsnn_export.network.dynamics.run_network`, the currents summed as the module
    docstring says. ``final_voltage`` is reported with and without isolation.
    """
    array = as_spike_array(spikes)
    w = np.ascontiguousarray(_numpy(weights), dtype=np.float32)
    if w.ndim != 2 or array.shape[2] != w.shape[0]:
        raise InvalidValueError(f"weights: spikes {array.shape} do not match weights {w.shape}")
    n, timesteps, n_inputs = array.shape
    n_neurons = w.shape[1]
    size = check_group(n_neurons, group)
    counts = np.zeros((n, n_neurons), dtype=np.int64)
    raster = np.zeros((n if record else 0, timesteps, n_neurons), dtype=np.bool_)
    final = np.zeros((n, n_neurons), dtype=np.float32)
    theta_array = np.ascontiguousarray(_numpy(theta), dtype=np.float32)
    parts = run_parts(n, n_neurons, size, torch.get_num_threads() if threads is None else threads, isolation)
    candidates = [np.zeros((len(range(n)[rows]), timesteps), dtype=np.int32) for rows, _, _ in parts]
    tile = neuron_tile(n_neurons, size)

    def task(k: int) -> Callable[[], None]:
        rows, start, stop = parts[k]
        return lambda: float_kernel(
            array[rows], w, theta_array, np.float32(beta), bool(wta), size, bool(isolation), bool(record), start,
            stop, tile, *current_blocks(timesteps, tile, len(range(n)[rows])), counts[rows], candidates[k],
            raster[rows] if record else raster, final[rows],
        )  # fmt: skip

    run_threads([task(k) for k in range(len(parts))])
    n_candidates = np.zeros((n, timesteps), dtype=np.int32)
    for (rows, _, _), part in zip(parts, candidates, strict=True):
        n_candidates[rows] += part
    raster_run = torch.from_numpy(raster) if record else None
    return SpikeRun(torch.from_numpy(counts), torch.from_numpy(n_candidates), raster_run, torch.from_numpy(final))
