"""The integer simulator's compiled, event-driven step loop: :func:`integer_run`.

The step equations are those of ``targets/intsim.py`` and ``export/model.py``:

    A_j = sum_{i active} (q_ij << shift)          (exact)
    V_j = min((V_j keep) >> 12 + A_j, limit)      (clips counted)
    C = {j : V_j > theta_j << shift}
    WTA on:   the first j in C maximising A_j m_j spikes
    WTA off:  every j in C spikes
    V_j <- 0 for every j in C

State is zeroed at the start of every presentation (isolation) or carried over in order. The
kernel is bit-identical to the integer simulator (:func:`vprsnn_export.targets.intsim.run_prepared`)
and its reference stepper. The neurons run in tiles of whole WTA groups, on threads
(:mod:`vprsnn_export.network.parallel`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.network.kernel_checks import require_array, require_groups, require_int
from vprsnn_export.network.kernel_sums import (
    ANY3,
    SPIKES,
    _all_step_lists,
    _column_blocks,
    _tile_currents,
    as_spike_array,
    compiled,
)
from vprsnn_export.network.parallel import check_group, current_blocks, neuron_tile, run_parts, run_threads
from vprsnn_export.network.runs import SpikeRun
from vprsnn_export.network.widths import DECAY_BITS

INT32_SAFE = (1 << 31) - 1


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
    current_store: np.ndarray,  # (chunk T tile,) scratch: int32 when every sum of q fits, else int64
    start: int,  # the neurons [start, stop) this call runs: whole WTA groups
    stop: int,
    tile: int,  # neurons per tile: whole WTA groups
    column: int,  # neurons per column block of a tile's current sums (network.parallel.current_blocks)
    chunk: int,  # presentations whose currents are summed before their steps
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
    saturations = 0
    peak = np.int64(0)
    store = np.empty(n_inputs * tile if n > 1 else 0, dtype=mantissas.dtype)  # none for a lone presentation: in place
    for g0 in range(start, stop, tile):
        width = min(tile, stop - g0)
        current = current_store[: chunk * timesteps * width].reshape((chunk, timesteps, width))
        _column_blocks(mantissas, g0, width, column, store)
        tile_threshold = threshold[g0 : g0 + width].copy()
        voltage = np.zeros(width, dtype=np.int64)
        candidate = np.zeros(width, dtype=np.bool_)
        for p in range(n):
            if p % chunk == 0:
                p1 = min(n, p + chunk)
                _tile_currents(mantissas, store, g0, width, column, index, offsets, p, p1, current)
            if isolation:
                voltage[:] = 0
            for t in range(timesteps):
                step = current[p % chunk, t]
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
    column: int,
    chunk: int,
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
    require_int(k, "column", column, 1)
    require_int(k, "chunk", chunk, 1)
    if current_store.shape[0] < (need := chunk * timesteps * tile):
        raise InvalidValueError(f"{k}: current_store holds {current_store.shape[0]} values, needs {need}")
    require_array(k, "counts", counts, (np.int64,), (n, n_neurons), writable=True)
    require_array(k, "n_candidates", n_candidates, (np.int32,), (n, timesteps), writable=True)
    require_array(k, "raster", raster, (np.bool_,), (n if record else None, timesteps, n_neurons), writable=True)
    require_array(k, "final", final, (np.int64,), (n, n_neurons), writable=True)
    return _integer_kernel(
        spikes, mantissas, int(shift), threshold, multipliers, bool(use_multipliers), int(keep), int(limit),
        bool(wta), int(group), bool(isolation), bool(record), current_store, int(start), int(stop), int(tile),
        int(column), int(chunk), counts, n_candidates, raster, final,
    )  # fmt: skip


@dataclass(frozen=True)
class KernelWeights:
    """Weight mantissas checked once and stored as the kernel reads them (a model's run reuses them every call).

    ``weights``: q_ij (inputs, neurons), C-contiguous, in the narrowest unsigned dtype that holds max q (uint8 up
    to 8 bits: a quarter of float32's memory traffic); ``bound`` = max_j sum_i q_ij, the largest unshifted current.
    """

    weights: np.ndarray
    bound: int


def kernel_weights(mantissas: np.ndarray) -> KernelWeights:
    """The mantissas as :class:`KernelWeights`; InvalidValueError when not 2-D or negative (the kernel relies on V >= 0)."""
    q = np.asarray(mantissas)
    if q.ndim != 2:
        raise InvalidValueError(f"mantissas: expected (inputs, neurons), got shape {q.shape}")
    if q.size and int(q.min()) < 0:
        raise InvalidValueError("mantissas: integer weights must be non-negative (the kernel relies on V >= 0)")
    top = int(q.max()) if q.size else 0
    bound = int(q.astype(np.int64).sum(axis=0).max()) if q.size else 0
    storage = np.uint8 if top < (1 << 8) else np.uint16 if top < (1 << 16) else np.int64
    return KernelWeights(np.ascontiguousarray(q, dtype=storage), bound)


def integer_run(
    spikes: torch.Tensor | np.ndarray,
    mantissas: np.ndarray | KernelWeights,
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

    ``group``: neurons per WTA group (:mod:`vprsnn_export.network.modules`); ``None``: one group.
    ``threads`` and the tiles of neurons as in :func:`float_run`.

    ``mantissas`` are the unshifted weights q_ij (inputs, neurons), non-negative, or the
    :class:`KernelWeights` made of them once (:func:`kernel_weights`); the kernel sums them in the narrowest
    dtype that holds them and shifts each current by ``shift``: (sum q) << s == sum (q << s).
    ``threshold`` is theta_j << shift, ``multipliers`` the m_j (``None`` when all equal: the WTA
    then compares a_j), ``keep`` = 4096 - dv, ``limit`` the largest voltage. ``max_current`` is
    reported unshifted, as the simulator does.
    """
    array = as_spike_array(spikes)
    prepared = mantissas if isinstance(mantissas, KernelWeights) else kernel_weights(mantissas)
    weights, bound = prepared.weights, prepared.bound
    if (bound << shift) >= (1 << 62):
        raise InvalidValueError(f"shift: current sums up to {bound} << {shift} overflow 64-bit voltages")
    n, timesteps, _ = array.shape
    n_neurons = weights.shape[1]
    size = check_group(n_neurons, group)
    thresholds = np.ascontiguousarray(threshold, dtype=np.int64)
    scores = np.ones(n_neurons, dtype=np.int64) if multipliers is None else np.ascontiguousarray(multipliers, np.int64)
    counts = np.zeros((n, n_neurons), dtype=np.int64)
    raster = np.zeros((n if record else 0, timesteps, n_neurons), dtype=np.bool_)
    final = np.zeros((n, n_neurons), dtype=np.int64)
    tile = neuron_tile(n_neurons, size)
    parts = run_parts(n, n_neurons, size, torch.get_num_threads() if threads is None else threads, isolation)
    candidates = [np.zeros((len(range(n)[rows]), timesteps), dtype=np.int32) for rows, _, _ in parts]

    def task(k: int) -> Callable[[], tuple[int, np.int64]]:
        rows, start, stop = parts[k]

        def run() -> tuple[int, np.int64]:
            column, chunk = current_blocks(timesteps, tile, len(range(n)[rows]))
            current_store = np.zeros(chunk * timesteps * tile, dtype=np.int32 if bound <= INT32_SAFE else np.int64)
            return integer_kernel(
                array[rows], weights, int(shift), thresholds, scores, multipliers is not None, int(keep), int(limit),
                bool(wta), size, bool(isolation), bool(record), current_store, start, stop, tile, column, chunk,
                counts[rows], candidates[k], raster[rows] if record else raster, final[rows],
            )  # fmt: skip

        return run

    extremes = run_threads([task(k) for k in range(len(parts))])  # (saturations, shifted peak) per part
    n_candidates = np.zeros((n, timesteps), dtype=np.int32)
    for (rows, _, _), part in zip(parts, candidates, strict=True):
        n_candidates[rows] += part
    return SpikeRun(
        counts=torch.from_numpy(counts),
        candidates_per_step=torch.from_numpy(n_candidates),
        raster=torch.from_numpy(raster) if record else None,
        final_voltage=torch.from_numpy(final),
        saturations=sum(int(e[0]) for e in extremes),
        max_current=max(int(e[1]) for e in extremes) >> shift,
    )
