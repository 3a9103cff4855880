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
order. The integer kernel is bit-identical to the integer simulator. The float
kernel sums each step's currents in increasing input order in float32 (or in float64
and rounds once, ``accumulate="float64"``); BLAS sums the same terms in its own order,
so a current may differ in its last bit from :func:`vprsnn_export.dynamics.run_network`
and, rarely, a threshold decision with it (bench/bench_kernels.py counts how often).

Compilation is lazy (first call, about a second per signature) and cached next to this
file (numba ``cache=True``); on a read-only install numba warns and compiles in memory.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import torch
from numba import njit

from .runs import SpikeRun

DECAY_BITS = 12  # V <- (V keep) >> 12: the integer decay's 12-bit fraction (export/model.py DECAY_BITS)
INT32_SAFE = (1 << 31) - 1


def as_spike_array(spikes: torch.Tensor | np.ndarray) -> np.ndarray:
    """Spikes (N, T, inputs) of 0/1 uint8 or bool as a C-contiguous uint8 numpy array (no copy when possible)."""
    array = spikes.detach().cpu().numpy() if isinstance(spikes, torch.Tensor) else np.asarray(spikes)
    if array.ndim != 3:
        raise ValueError(f"expected spikes of shape (N, T, inputs), got {array.shape}")
    if array.dtype == np.bool_:
        array = array.view(np.uint8)
    if array.dtype != np.uint8:
        raise ValueError(f"expected uint8 or bool spikes, got {array.dtype}")
    return np.ascontiguousarray(array)


@njit(cache=True, nogil=True)
def _active_inputs(row: np.ndarray, index: np.ndarray) -> int:
    """Write the indices i with row[i] != 0 into index[:k], in increasing order; return k."""
    k = 0
    for i in range(row.shape[0]):
        if row[i]:
            index[k] = i
            k += 1
    return k


@njit(cache=True, nogil=True)
def _integer_kernel(
    spikes: np.ndarray,  # (N, T, inputs) uint8
    weights: np.ndarray,  # (inputs, neurons) int32 or int64: q << shift
    threshold: np.ndarray,  # (neurons,) int64: theta << shift
    multipliers: np.ndarray,  # (neurons,) int64 m_j
    use_multipliers: bool,
    keep: int,
    limit: int,
    wta: bool,
    isolation: bool,
    record: bool,
    current: np.ndarray,  # (neurons,) scratch of the current's dtype (int32 when sums fit)
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int]:
    n, timesteps, n_inputs = spikes.shape
    n_neurons = weights.shape[1]
    counts = np.zeros((n, n_neurons), dtype=np.int64)
    n_candidates = np.zeros((n, timesteps), dtype=np.int32)
    raster = np.zeros((n if record else 0, timesteps, n_neurons), dtype=np.bool_)
    final = np.zeros((n, n_neurons), dtype=np.int64)
    voltage = np.zeros(n_neurons, dtype=np.int64)
    index = np.empty(n_inputs, dtype=np.int64)
    saturations = 0
    peak = 0
    for p in range(n):
        if isolation:
            voltage[:] = 0
        for t in range(timesteps):
            k = _active_inputs(spikes[p, t], index)
            current[:] = 0
            for a in range(k):
                current += weights[index[a]]
            n_cand = 0
            best = -1
            best_score = -1
            for j in range(n_neurons):
                c = np.int64(current[j])
                if c > peak:
                    peak = c
                v = ((voltage[j] * keep) >> DECAY_BITS) + c
                if v > limit:
                    saturations += 1
                    v = limit
                if v > threshold[j]:
                    n_cand += 1
                    v = 0
                    if wta:
                        score = c * multipliers[j] if use_multipliers else c
                        if score > best_score:
                            best_score = score
                            best = j
                    else:
                        counts[p, j] += 1
                        if record:
                            raster[p, t, j] = True
                voltage[j] = v
            n_candidates[p, t] = n_cand
            if wta and best >= 0:
                counts[p, best] += 1
                if record:
                    raster[p, t, best] = True
        final[p] = voltage
    return counts, n_candidates, raster, final, saturations, peak


@njit(cache=True, nogil=True)
def _float_kernel(
    spikes: np.ndarray,  # (N, T, inputs) uint8
    weights: np.ndarray,  # (inputs, neurons) float32
    theta: np.ndarray,  # (neurons,) float32
    beta: np.float32,
    wta: bool,
    isolation: bool,
    record: bool,
    accumulator: np.ndarray,  # (neurons,) float32 or float64 scratch: the dtype the currents are summed in
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    n, timesteps, n_inputs = spikes.shape
    n_neurons = weights.shape[1]
    counts = np.zeros((n, n_neurons), dtype=np.int64)
    n_candidates = np.zeros((n, timesteps), dtype=np.int32)
    raster = np.zeros((n if record else 0, timesteps, n_neurons), dtype=np.bool_)
    final = np.zeros((n, n_neurons), dtype=np.float32)
    voltage = np.zeros(n_neurons, dtype=np.float32)
    index = np.empty(n_inputs, dtype=np.int64)
    for p in range(n):
        if isolation:
            voltage[:] = 0
        for t in range(timesteps):
            k = _active_inputs(spikes[p, t], index)
            accumulator[:] = 0
            for a in range(k):
                accumulator += weights[index[a]]
            n_cand = 0
            best = -1
            best_current = np.float32(-np.inf)
            for j in range(n_neurons):
                c = np.float32(accumulator[j])
                v = beta * voltage[j] + c
                if v > theta[j]:
                    n_cand += 1
                    v = np.float32(0)
                    if wta:
                        if best < 0 or c > best_current:
                            best_current = c
                            best = j
                    else:
                        counts[p, j] += 1
                        if record:
                            raster[p, t, j] = True
                voltage[j] = v
            n_candidates[p, t] = n_cand
            if wta and best >= 0:
                counts[p, best] += 1
                if record:
                    raster[p, t, best] = True
        final[p] = voltage
    return counts, n_candidates, raster, final


def integer_run(
    spikes: torch.Tensor | np.ndarray,
    weights: np.ndarray,
    threshold: np.ndarray,
    multipliers: np.ndarray | None,
    *,
    keep: int,
    limit: int,
    shift: int,
    wta: bool,
    isolation: bool = True,
    record: bool = False,
) -> SpikeRun:
    """The integer simulator's run, event-driven and compiled; bit-identical to ``targets.intsim.run_prepared``.

    ``weights`` are the shifted mantissas q_ij << shift (inputs, neurons), ``threshold`` theta_j << shift,
    ``multipliers`` the m_j (``None`` when all equal: the WTA then compares a_j), ``keep`` = 4096 - dv,
    ``limit`` the largest voltage. ``max_current`` is reported unshifted, as the simulator does.
    """
    array = as_spike_array(spikes)
    shifted = np.asarray(weights, dtype=np.int64)
    if shifted.ndim != 2 or array.shape[2] != shifted.shape[0]:
        raise ValueError(f"spikes {array.shape} do not match weights {shifted.shape}")
    if shifted.size and int(shifted.min()) < 0:
        raise ValueError("integer weights must be non-negative (the kernel relies on V >= 0)")
    bound = int(shifted.sum(axis=0).max()) if shifted.size else 0
    narrow = bound <= INT32_SAFE
    n_neurons = shifted.shape[1]
    counts, n_candidates, raster, final, saturations, peak = _integer_kernel(
        array,
        np.ascontiguousarray(shifted, dtype=np.int32 if narrow else np.int64),
        np.ascontiguousarray(threshold, dtype=np.int64),
        np.ones(n_neurons, dtype=np.int64) if multipliers is None else np.ascontiguousarray(multipliers, np.int64),
        multipliers is not None,
        int(keep),
        int(limit),
        bool(wta),
        bool(isolation),
        bool(record),
        np.zeros(n_neurons, dtype=np.int32 if narrow else np.int64),
    )
    return SpikeRun(
        counts=torch.from_numpy(counts),
        candidates_per_step=torch.from_numpy(n_candidates),
        raster=torch.from_numpy(raster) if record else None,
        final_voltage=torch.from_numpy(final),
        saturations=int(saturations),
        max_current=int(peak) >> shift,
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
    accumulate: Literal["float32", "float64"] = "float32",
) -> SpikeRun:
    """The float network's run (plasticity off), event-driven and compiled, on the CPU.

    Same dynamics as :func:`vprsnn_export.dynamics.run_network`; each step's currents are the
    weight rows of the active inputs summed in increasing input order in ``accumulate``
    precision, then rounded to float32. ``final_voltage`` is reported with and without isolation.
    """
    array = as_spike_array(spikes)
    w = np.ascontiguousarray(_numpy(weights), dtype=np.float32)
    if w.ndim != 2 or array.shape[2] != w.shape[0]:
        raise ValueError(f"spikes {array.shape} do not match weights {w.shape}")
    if accumulate not in ("float32", "float64"):
        raise ValueError(f"accumulate must be 'float32' or 'float64', got {accumulate!r}")
    counts, n_candidates, raster, final = _float_kernel(
        array,
        w,
        np.ascontiguousarray(_numpy(theta), dtype=np.float32),
        np.float32(beta),
        bool(wta),
        bool(isolation),
        bool(record),
        np.zeros(w.shape[1], dtype=np.dtype(accumulate)),
    )
    return SpikeRun(
        counts=torch.from_numpy(counts),
        candidates_per_step=torch.from_numpy(n_candidates),
        raster=torch.from_numpy(raster) if record else None,
        final_voltage=torch.from_numpy(final),
    )


def _numpy(values: torch.Tensor | np.ndarray) -> np.ndarray:
    return values.detach().cpu().numpy() if isinstance(values, torch.Tensor) else np.asarray(values)
