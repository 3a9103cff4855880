"""What every compiled kernel shares: the numba decorator, spike arrays, per-step lists of the
active inputs and the ordered sum of their weight rows.

The input is sparse (about 98 of 784 inputs spike per step), so instead of a dense matmul each step sums only
the weight rows of the inputs that spiked (:func:`_row_sum`), and the whole recurrence over presentations, steps
and neurons runs in one numba-compiled loop (no Python call per step). The sums run in increasing input order on
every CPU and at every thread count, so a seed fixes every weight and spike whatever the machine; a BLAS matmul
(the torch loop: GPU, ``compiled=False``) blocks its sums in an order of its own that differs between builds,
CPUs and shapes, and agrees with the kernels to float32 rounding.

The kernels, each beside its caller with its checked entry point: the Bernoulli encoder
(:mod:`vprsnn_export.data.encoding_kernel`), the float network (:mod:`vprsnn_export.network.dynamics_kernel`),
the integer simulator (:mod:`vprsnn_export.targets.intsim_kernel`) and the STDP training window
(:mod:`vprsnn_export.trainer.stdp_kernel`); threads and tiles: :mod:`vprsnn_export.network.parallel`.

Compilation is lazy (first call, about a second per signature) and cached next to the kernel's
file (numba ``cache=True``); on a read-only install without a writable cache directory the
kernels are compiled in memory with one warning (:func:`compiled`).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import TypeVar, cast

import numpy as np
import torch
from numba import njit

from ..errors import InvalidValueError

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
    array = _numpy(spikes)
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
    n, timesteps, _ = spikes.shape
    index = np.empty(np.count_nonzero(spikes) + 1, dtype=np.int32)
    offsets = np.empty((n, timesteps + 1), dtype=np.int64)
    k = 0
    for p in range(n):
        _step_lists(spikes[p], index[k:], offsets[p])
        for t in range(timesteps + 1):
            offsets[p, t] += k
        k = offsets[p, timesteps]
    return index, offsets


@compiled
def _row_sum(weights: np.ndarray, index: np.ndarray, k: int, total: np.ndarray, offset: int = 0) -> None:
    """total_j = (((0 + w_{i_1, o+j}) + w_{i_2, o+j}) + ...) + w_{i_k, o+j}: the weight rows of the active inputs
    index[:k] from column o = ``offset`` on, summed in float32 in increasing input order (the same on every CPU;
    0 when none is active).

    Eight rows are added per pass over ``total``, still one after another in that order, so each number is
    the same as one row per pass with an eighth of the loads and stores of ``total`` (1.2-1.5x at 27k neurons).
    Each row is sliced to the columns first and read at j from 0 on: indexed at ``offset + j`` numba cannot prove
    the index non-negative, keeps its wraparound check and the loop stays scalar (several times slower, the same
    bits: bench/bench_row_sum.py measures both side by side).
    """
    n = total.shape[0]
    stop = offset + n
    for j in range(n):
        total[j] = 0
    a = 0
    while a + 8 <= k:
        r0, r1 = weights[index[a]][offset:stop], weights[index[a + 1]][offset:stop]
        r2, r3 = weights[index[a + 2]][offset:stop], weights[index[a + 3]][offset:stop]
        r4, r5 = weights[index[a + 4]][offset:stop], weights[index[a + 5]][offset:stop]
        r6, r7 = weights[index[a + 6]][offset:stop], weights[index[a + 7]][offset:stop]
        for j in range(n):
            total[j] = (((((((total[j] + r0[j]) + r1[j]) + r2[j]) + r3[j]) + r4[j]) + r5[j]) + r6[j]) + r7[j]
        a += 8
    for b in range(a, k):
        row = weights[index[b]][offset:stop]
        for j in range(n):
            total[j] += row[j]


@compiled
def _column_blocks(weights: np.ndarray, g0: int, width: int, column: int, store: np.ndarray) -> None:
    """Copy the tile weights[:, g0:g0 + width] into ``store`` as contiguous (inputs, columns) blocks of ``column``
    neurons, block after block (:func:`_tile_currents` reads them); nothing into an empty ``store`` (a lone
    presentation's, read in place)."""
    if store.shape[0] == 0:
        return
    n_inputs = weights.shape[0]
    for c0 in range(0, width, column):
        columns = min(column, width - c0)
        block_weights = store[n_inputs * c0 : n_inputs * (c0 + columns)].reshape((n_inputs, columns))
        for i in range(n_inputs):
            for jj in range(columns):
                block_weights[i, jj] = weights[i, g0 + c0 + jj]


@compiled
def _block_currents(
    weights: np.ndarray,
    offset: int,
    c0: int,
    columns: int,
    index: np.ndarray,
    offsets: np.ndarray,
    p0: int,
    p1: int,
    current: np.ndarray,
) -> None:
    """current[p - p0, t, c0:c0 + columns] = the rows of step (p, t)'s active inputs from column ``offset`` on."""
    for p in range(p0, p1):
        for t in range(current.shape[1]):
            first, last = offsets[p, t], offsets[p, t + 1]
            _row_sum(weights, index[first:last], last - first, current[p - p0, t, c0 : c0 + columns], offset)


@compiled
def _tile_currents(
    weights: np.ndarray,
    store: np.ndarray,
    g0: int,
    width: int,
    column: int,
    index: np.ndarray,
    offsets: np.ndarray,
    p0: int,
    p1: int,
    current: np.ndarray,
) -> None:
    """current[p - p0, t] = the currents (:func:`_row_sum`) of the tile's neurons [g0, g0 + width) for presentations
    [p0, p1) at every step, one column block of ``column`` neurons at a time: from the tile's blocks in ``store``
    (:func:`_column_blocks`: its weights stay in cache across the presentations), or with an empty ``store`` (a lone
    presentation's: copying 169 MB of weights to sum one frame's rows cost 4x the sums) from the (inputs, neurons)
    weights in place."""
    n_inputs = weights.shape[0]
    for c0 in range(0, width, column):
        columns = min(column, width - c0)
        if store.shape[0] == 0:
            _block_currents(weights, g0 + c0, c0, columns, index, offsets, p0, p1, current)
        else:
            block = store[n_inputs * c0 : n_inputs * (c0 + columns)].reshape((n_inputs, columns))
            _block_currents(block, 0, c0, columns, index, offsets, p0, p1, current)


# Every compiled kernel is called from Python only through a checked entry point beside it, which
# refuses any array the kernel would index out of bounds (numba checks no bounds).
SPIKES = (np.uint8,)
ANY3 = (None, None, None)
