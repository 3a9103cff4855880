"""What every compiled kernel shares: the numba decorator, spike arrays, per-step lists of the
active inputs, the blocked sum of their weight rows and the probes of this machine's BLAS order.

The input is sparse (about 98 of 784 inputs spike per step), so instead of a dense matmul each
step sums only the weight rows of the inputs that spiked (:func:`_blocked_sum`), and the whole
recurrence over presentations, steps and neurons runs in one numba-compiled loop (no Python call
per step). Float sums follow the order this machine's BLAS uses for the dense matmul where a
probe finds it (:func:`blas_block`, :func:`batch_sums_in_order`), so the compiled paths reproduce
the torch ones bit for bit there; elsewhere they sum in their own fixed order (:func:`kernel_block`:
inputs left to right), which is the same on every CPU, so a seed still fixes every weight and
spike, and the torch loop (GPU, ``compiled=False``) agrees with them to float32 rounding.

The kernels, each beside its caller with its checked entry point: the Bernoulli encoder
(:mod:`vprsnn_export.data.encoding_kernel`), the float network (:mod:`vprsnn_export.network.dynamics_kernel`),
the integer simulator (:mod:`vprsnn_export.targets.intsim_kernel`) and the STDP training window
(:mod:`vprsnn_export.trainer.stdp_kernel`); threads and tiles: :mod:`vprsnn_export.network.parallel`.

Compilation is lazy (first call, about a second per signature) and cached next to the kernel's
file (numba ``cache=True``); on a read-only install without a writable cache directory the
kernels are compiled in memory with one warning (:func:`compiled`).
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable
from typing import TypeVar, cast

import numpy as np
import torch
from numba import njit

from ..errors import InvalidValueError
from .kernel_checks import require_array, require_int

F = TypeVar("F", bound=Callable[..., object])
_uncached: list[str] = []


def compiled(function: F) -> F:
    """numba ``njit(nogil=True, error_model="numpy")``, cached on disk when a cache directory is writable.

    numpy's error model: no Python zero-divisor check per division (the kernels never divide by
    zero), so divisions in loops vectorise; the results of every other division are the same.

    numba caches next to the kernel's file, else in the user's cache directory (or ``NUMBA_CACHE_DIR``);
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


def _numpy(values: torch.Tensor | np.ndarray) -> np.ndarray:
    return values.detach().cpu().numpy() if isinstance(values, torch.Tensor) else np.asarray(values)


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
def _column_blocks(weights: np.ndarray, g0: int, width: int, column: int, store: np.ndarray) -> None:
    """Copy the tile weights[:, g0:g0 + width] into ``store`` as contiguous (inputs, columns) blocks of ``column``
    neurons, block after block (:func:`_tile_currents` reads them)."""
    n_inputs = weights.shape[0]
    for c0 in range(0, width, column):
        columns = min(column, width - c0)
        block_weights = store[n_inputs * c0 : n_inputs * (c0 + columns)].reshape((n_inputs, columns))
        for i in range(n_inputs):
            for jj in range(columns):
                block_weights[i, jj] = weights[i, g0 + c0 + jj]


@compiled
def _tile_currents(
    store: np.ndarray,
    n_inputs: int,
    width: int,
    column: int,
    index: np.ndarray,
    offsets: np.ndarray,
    p0: int,
    p1: int,
    block: int,
    current: np.ndarray,
    partial_store: np.ndarray,
) -> None:
    """current[p - p0, t] = the tile's currents (:func:`_blocked_sum`) of presentations [p0, p1) at every step,
    one column block of :func:`_column_blocks` at a time (its weights stay in cache across the presentations)."""
    for c0 in range(0, width, column):
        columns = min(column, width - c0)
        block_weights = store[n_inputs * c0 : n_inputs * (c0 + columns)].reshape((n_inputs, columns))
        partial = partial_store[:columns]
        for p in range(p0, p1):
            for t in range(current.shape[1]):
                first, last = offsets[p, t], offsets[p, t + 1]
                total = current[p - p0, t, c0 : c0 + columns]
                _blocked_sum(block_weights, index[first:last], last - first, block, total, partial)


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


# Every compiled kernel is called from Python only through a checked entry point beside it, which
# refuses any array the kernel would index out of bounds (numba checks no bounds).
SPIKES = (np.uint8,)
ANY3 = (None, None, None)


def blocked_currents(spikes: np.ndarray, weights: np.ndarray, block: int) -> np.ndarray:
    """:func:`_blocked_currents` once its arrays are checked (InvalidValueError naming them)."""
    k = "blocked currents"
    require_array(k, "spikes", spikes, SPIKES, (None, None))
    require_array(k, "weights", weights, (np.float32,), (spikes.shape[1], None))
    return _blocked_currents(spikes, weights, require_int(k, "block", block, 1))


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


def kernel_block(rows: int, n_inputs: int, n_neurons: int) -> int:
    """The K-block the compiled kernels sum currents in: :func:`blas_block` where it is found, else all
    inputs left to right (one block), an order that does not depend on the machine.

    MKL 2024.2 on AVX-512 blocks by 384 from about 200 rows but uses an order none of the
    candidates reproduces for the training batch (64 rows): there the kernels keep their own
    order rather than fall back to the torch loop (about 30x slower).
    """
    return blas_block(rows, n_inputs, n_neurons) or n_inputs


def matches_torch(rows: int, n_inputs: int, n_neurons: int) -> bool:
    """Whether the compiled kernels reproduce torch's CPU matmul bit for bit for this shape (both probes succeed)."""
    return blas_block(rows, n_inputs, n_neurons) is not None and batch_sums_in_order(rows, n_inputs, n_neurons)


def batch_sums_in_order(batch: int, n_inputs: int, n_neurons: int) -> bool:
    """Whether torch's x^T @ y over a batch (the STDP terms) sums the rows left to right on this machine."""
    return _probe_batch_sums(batch, n_inputs, n_neurons, torch.get_num_threads())
