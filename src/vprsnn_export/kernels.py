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

Compilation is lazy (first call, about a second per signature) and cached next to this
file (numba ``cache=True``); on a read-only install without a writable cache directory the
kernels are compiled in memory with one warning (:func:`compiled`). The kernels are serial:
numba's threading layer is never launched (once launched, its OpenMP workers slowed torch's
training loop sevenfold here).
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar, cast

import numpy as np
import torch
from numba import njit

from .config import Config
from .runs import SpikeRun

DECAY_BITS = 12  # V <- (V keep) >> 12: the integer decay's 12-bit fraction (export/model.py DECAY_BITS)
INT32_SAFE = (1 << 31) - 1
QUERY_CHUNK = 128  # presentations run_network multiplies at once: bounds its (chunk, T, neurons) currents


F = TypeVar("F", bound=Callable[..., object])
_uncached: list[str] = []


def compiled(function: F) -> F:
    """numba ``njit(nogil=True)``, cached on disk when a cache directory is writable.

    numba caches next to this file, else in the user's cache directory (or ``NUMBA_CACHE_DIR``);
    when none is writable (a read-only install and home) numba refuses ``cache=True`` at import,
    so the kernels are compiled in memory on first call instead, with one warning.
    """
    try:
        return cast(F, njit(cache=True, nogil=True)(function))
    except RuntimeError as exc:
        if not _uncached:
            warnings.warn(f"numba cannot cache the kernels ({exc}); compiling them in memory", stacklevel=2)
        _uncached.append(function.__name__)
        return cast(F, njit(nogil=True)(function))


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
def _step_currents(
    weights: np.ndarray, index: np.ndarray, offsets: np.ndarray, block: int, out: np.ndarray, partial: np.ndarray
) -> None:
    """out[t] = sum of the weight rows listed for step t, summed as :func:`_blocked_sum` does.

    Whole rows at a time (numba vectorises the row additions; tiling the neurons to keep
    weight rows in L2 measured slower here: the per-tile overhead outweighs the misses).
    """
    for t in range(out.shape[0]):
        start, end = offsets[t], offsets[t + 1]
        _blocked_sum(weights, index[start:end], end - start, block, out[t], partial)


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
    current: np.ndarray,  # (T, neurons) scratch: int32 when every sum of q fits, else int64
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, np.int64]:
    n, timesteps, n_inputs = spikes.shape
    n_neurons = mantissas.shape[1]
    counts = np.zeros((n, n_neurons), dtype=np.int64)
    n_candidates = np.zeros((n, timesteps), dtype=np.int32)
    raster = np.zeros((n if record else 0, timesteps, n_neurons), dtype=np.bool_)
    final = np.zeros((n, n_neurons), dtype=np.int64)
    voltage = np.zeros(n_neurons, dtype=np.int64)
    index = np.empty(timesteps * n_inputs + 1, dtype=np.int64)
    offsets = np.empty(timesteps + 1, dtype=np.int64)
    partial = np.empty(n_neurons, dtype=current.dtype)
    saturations = 0
    peak = np.int64(0)
    for p in range(n):
        if isolation:
            voltage[:] = 0
        _step_lists(spikes[p], index, offsets)
        _step_currents(mantissas, index, offsets, n_inputs, current, partial)
        for t in range(timesteps):
            n_cand = 0
            for g in range(0, n_neurons, group):
                best = -1
                best_score = np.int64(-1)
                for j in range(g, g + group):
                    c = np.int64(current[t, j]) << shift
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
                if wta and best >= 0:
                    counts[p, best] += 1
                    if record:
                        raster[p, t, best] = True
            n_candidates[p, t] = n_cand
        final[p] = voltage
    return counts, n_candidates, raster, final, saturations, peak


@compiled
def _blocked_sum(
    weights: np.ndarray, index: np.ndarray, k: int, block: int, total: np.ndarray, partial: np.ndarray
) -> None:
    """total = sum over the active rows index[:k] of weights, the way a K-blocked GEMM adds them.

    Inputs are cut into blocks of ``block`` consecutive indices; each block's rows are summed
    from zero in increasing order, and the block sums are added to the total in order
    (``block`` >= the number of inputs: one plain left-to-right sum).
    """
    total[:] = 0
    a = 0
    first = True
    while a < k:
        stop = (index[a] // block + 1) * block
        partial[:] = 0
        while a < k and index[a] < stop:
            partial += weights[index[a]]
            a += 1
        if first:
            total[:] = partial
            first = False
        else:
            total += partial


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
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    n, timesteps, n_inputs = spikes.shape
    n_neurons = weights.shape[1]
    counts = np.zeros((n, n_neurons), dtype=np.int64)
    n_candidates = np.zeros((n, timesteps), dtype=np.int32)
    raster = np.zeros((n if record else 0, timesteps, n_neurons), dtype=np.bool_)
    final = np.zeros((n, n_neurons), dtype=np.float32)
    voltage = np.zeros(n_neurons, dtype=np.float32)
    current = np.empty((timesteps, n_neurons), dtype=np.float32)
    partial = np.empty(n_neurons, dtype=np.float32)
    index = np.empty(timesteps * n_inputs + 1, dtype=np.int64)
    offsets = np.empty(timesteps + 1, dtype=np.int64)
    for p in range(n):
        if isolation:
            voltage[:] = 0
        _step_lists(spikes[p], index, offsets)
        _step_currents(weights, index, offsets, block, current, partial)
        for t in range(timesteps):
            n_cand = 0
            for g in range(0, n_neurons, group):
                best = -1
                best_current = np.float32(-np.inf)
                for j in range(g, g + group):
                    c = current[t, j]
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
                if wta and best >= 0:
                    counts[p, best] += 1
                    if record:
                        raster[p, t, best] = True
            n_candidates[p, t] = n_cand
        final[p] = voltage
    return counts, n_candidates, raster, final


def check_group(n_neurons: int, group: int | None) -> int:
    """The WTA group size: ``n_neurons`` for ``None``; ValueError unless it divides ``n_neurons``."""
    size = n_neurons if group is None else int(group)
    if size < 1 or n_neurons % size:
        raise ValueError(f"WTA groups of {size} neurons do not divide {n_neurons} neurons")
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
) -> SpikeRun:
    """The integer simulator's run, event-driven and compiled; bit-identical to ``targets.intsim.run_prepared``.

    ``group``: neurons per WTA group (:mod:`vprsnn_export.modules`); ``None``: one group.

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
        raise ValueError(f"spikes {array.shape} do not match weights {q.shape}")
    if q.size and int(q.min()) < 0:
        raise ValueError("integer weights must be non-negative (the kernel relies on V >= 0)")
    top = int(q.max()) if q.size else 0
    bound = int(q.astype(np.int64).sum(axis=0).max()) if q.size else 0
    if (bound << shift) >= (1 << 62):
        raise ValueError(f"current sums up to {bound} << {shift} overflow 64-bit voltages")
    storage = np.uint8 if top < (1 << 8) else np.uint16 if top < (1 << 16) else np.int64
    n_neurons = q.shape[1]
    counts, n_candidates, raster, final, saturations, peak = _integer_kernel(
        array,
        np.ascontiguousarray(q, dtype=storage),
        int(shift),
        np.ascontiguousarray(threshold, dtype=np.int64),
        np.ones(n_neurons, dtype=np.int64) if multipliers is None else np.ascontiguousarray(multipliers, np.int64),
        multipliers is not None,
        int(keep),
        int(limit),
        bool(wta),
        check_group(n_neurons, group),
        bool(isolation),
        bool(record),
        np.zeros((array.shape[1], n_neurons), dtype=np.int32 if bound <= INT32_SAFE else np.int64),
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
    block: int | None = None,
    group: int | None = None,
) -> SpikeRun:
    """The float network's run (plasticity off), event-driven and compiled, on the CPU.

    ``group``: neurons per WTA group (:mod:`vprsnn_export.modules`); ``None``: one group.

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
        raise ValueError(f"spikes {array.shape} do not match weights {w.shape}")
    n, timesteps, n_inputs = array.shape
    if block is None:
        block = blas_block(max(1, min(n, QUERY_CHUNK) * timesteps), n_inputs, w.shape[1]) or n_inputs
    counts, n_candidates, raster, final = _float_kernel(
        array,
        w,
        np.ascontiguousarray(_numpy(theta), dtype=np.float32),
        np.float32(beta),
        bool(wta),
        check_group(w.shape[1], group),
        bool(isolation),
        bool(record),
        max(1, int(block)),
    )
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
        if np.array_equal(_blocked_currents(packed, weights, max(size, 1)), expected):
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
    """The training window, computing only the weight columns a step can change.

    dW_ij = A+ (w_max - w_ij) P_ij - A- w_ij D_ij with P_ij = sum_b x_bi S_bj and
    D_ij = sum_b s_bi y_bj (b in order). y_bj is exactly 0 until neuron j has fired in row b and
    S_bj is 0 unless it fires now, so both sums skip their zero terms (adding an exact 0 changes
    no float) and dW_ij = +0 (W unchanged) outside the columns j some row has fired into
    ("traced"). Column normalisation divides column j by its norm n_j every step; once n_j
    is exactly 1.0f the division is the identity, so such a column ("settled") stays unchanged
    until it is traced again. Every other column is updated and normalised as in the dense loop,
    each float32 operation in the same order.
    """
    batch, timesteps, n_inputs = spikes.shape
    n_neurons = weights.shape[1]
    zero = np.float32(0)
    tiny = np.float32(np.finfo(np.float32).tiny)
    voltage = np.zeros((batch, n_neurons), dtype=np.float32)
    post_trace = np.zeros((batch, n_neurons), dtype=np.float32)
    pre_trace = np.zeros((batch, n_inputs), dtype=np.float32)
    current = np.empty((batch, n_neurons), dtype=np.float32)
    fired = np.zeros((batch, n_neurons), dtype=np.bool_)
    partial = np.empty(n_neurons, dtype=np.float32)
    index = np.empty((batch, n_inputs), dtype=np.int64)
    n_active = np.empty(batch, dtype=np.int64)
    traced = np.empty((batch, n_neurons), dtype=np.int64)  # per row: the neurons that have fired, in first-firing order
    n_traced = np.zeros(batch, dtype=np.int64)
    winners = np.empty((batch, n_neurons), dtype=np.int64)  # per row: the neurons firing this step
    n_winners = np.zeros(batch, dtype=np.int64)
    settled = np.zeros(n_neurons, dtype=np.bool_)  # column norm exactly 1.0f and column unchanged since
    column = np.full(n_neurons, -1, dtype=np.int64)  # neuron -> its slot among this step's columns
    columns = np.empty(n_neurons, dtype=np.int64)
    potentiation_store = np.empty(n_inputs * n_neurons, dtype=np.float32)  # (inputs, slots)
    depression_store = np.empty(n_inputs * n_neurons, dtype=np.float32)  # (inputs, slots)
    gathered_store = np.empty(n_inputs * n_neurons, dtype=np.float32)  # (inputs, slots): the columns' weights
    squares = np.empty(n_neurons, dtype=np.float32)
    fired_total = np.zeros(n_neurons, dtype=np.float32)
    for t in range(timesteps):
        for b in range(batch):
            n_active[b] = _active_inputs(spikes[b, t], index[b])
            _blocked_sum(weights, index[b], n_active[b], block, current[b], partial)
        for b in range(batch):
            best = -1
            best_current = np.float32(-np.inf)
            n_winners[b] = 0
            for j in range(n_neurons):
                c = current[b, j]
                v = beta * voltage[b, j] + c
                candidate = v > theta[j]
                fired[b, j] = candidate and not wta
                if candidate:
                    voltage[b, j] = zero
                    if not wta:
                        winners[b, n_winners[b]] = j
                        n_winners[b] += 1
                    if best < 0 or c > best_current:
                        best_current = c
                        best = j
                else:
                    voltage[b, j] = v
            if wta and best >= 0:
                fired[b, best] = True
                winners[b, 0] = best
                n_winners[b] = 1
        for b in range(batch):
            for i in range(n_inputs):
                pre_trace[b, i] = pre_trace[b, i] * pre_keep + np.float32(spikes[b, t, i])
            for q in range(n_traced[b]):  # y_bj = 0 (exactly, as 0 keep + 0) for every other neuron
                j = traced[b, q]
                post_trace[b, j] = post_trace[b, j] * post_keep + (np.float32(1) if fired[b, j] else zero)
            for w in range(n_winners[b]):
                j = winners[b, w]
                fired_total[j] += np.float32(1)
                if not _listed(traced[b], n_traced[b], j):  # first firing: y_bj = 0 keep + 1
                    post_trace[b, j] = np.float32(1)
                    traced[b, n_traced[b]] = j
                    n_traced[b] += 1
        m = 0
        for b in range(batch):
            for q in range(n_traced[b]):
                j = traced[b, q]
                if column[j] < 0:
                    column[j] = m
                    columns[m] = j
                    m += 1
        if weight_norm:
            for j in range(n_neurons):
                if column[j] < 0 and not settled[j]:
                    column[j] = m
                    columns[m] = j
                    m += 1
        potentiation = potentiation_store[: n_inputs * m].reshape((n_inputs, m))
        depression = depression_store[: n_inputs * m].reshape((n_inputs, m))
        gathered = gathered_store[: n_inputs * m].reshape((n_inputs, m))
        potentiation[:] = zero
        depression[:] = zero
        for b in range(batch):
            for w in range(n_winners[b]):
                slot = column[winners[b, w]]
                for i in range(n_inputs):
                    potentiation[i, slot] += pre_trace[b, i]
            for a in range(n_active[b]):
                row = depression[index[b, a]]
                for q in range(n_traced[b]):
                    j = traced[b, q]
                    row[column[j]] += post_trace[b, j]
        for i in range(n_inputs):  # gather, update in contiguous (vectorised) rows, scatter
            for slot in range(m):
                gathered[i, slot] = weights[i, columns[slot]]
        squares[:m] = zero
        for i in range(n_inputs):
            for slot in range(m):
                w = gathered[i, slot]
                delta = a_plus * (w_max - w) * potentiation[i, slot] - a_minus * w * depression[i, slot]
                w = min(max(w + delta, zero), w_max)
                gathered[i, slot] = w
                squares[slot] += w * w
        if weight_norm:
            for slot in range(m):
                squares[slot] = max(np.sqrt(squares[slot]), tiny)
                settled[columns[slot]] = squares[slot] == np.float32(1)
            for i in range(n_inputs):
                for slot in range(m):
                    gathered[i, slot] = gathered[i, slot] / squares[slot]
        for i in range(n_inputs):
            for slot in range(m):
                weights[i, columns[slot]] = gathered[i, slot]
        for slot in range(m):
            column[columns[slot]] = -1
    return fired_total


@compiled
def _listed(values: np.ndarray, n: int, value: int) -> bool:
    """Whether value is among values[:n]."""
    for k in range(n):
        if values[k] == value:
            return True
    return False


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
    fired = _stdp_window(
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
        raise ValueError(f"expected (N, D) probabilities and N seeds, got {p.shape} and {len(seeds)}")
    limits = bernoulli_limits(p)
    out = np.empty((p.shape[0], int(timesteps), p.shape[1]), dtype=np.uint8)
    _bernoulli_kernel(limits, generator_seeds(seeds), int(timesteps), out)
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
        return _stdp_windows(
            limits[part], seeds[part], sizes[part], blocks[part], timesteps, weights[part], theta[part], *args
        )

    parts = module_slices(n_modules, threads)
    if len(parts) == 1:
        return run(parts[0])
    with ThreadPoolExecutor(max_workers=len(parts)) as pool:
        return np.concatenate(list(pool.map(run, parts)))
