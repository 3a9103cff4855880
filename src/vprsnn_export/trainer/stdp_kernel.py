"""The compiled STDP training window: the step loop of ``train.train_batch`` in one call.

:func:`stdp_window` is the training window (WTA step, traces, STDP, clip, column normalisation)
with every float32 operation in the torch loop's order but the currents, which are summed in increasing
input order on every CPU (:func:`vprsnn_export.network.kernel_sums._row_sum`; the torch loop's BLAS blocks
them its own way), so the weights agree with the torch loop's to float32 rounding and a seed fixes them
on every machine.
:func:`stdp_windows` runs that window for M independent modules of an ensemble in one call,
encoding each module's batch inside it (:mod:`vprsnn_export.data.encoding_kernel`), on threads over
contiguous slices of modules (:func:`vprsnn_export.network.parallel.module_slices`).
"""

from __future__ import annotations

from functools import partial

import numpy as np
import torch

from vprsnn_export.config import Config
from vprsnn_export.data.encoding_kernel import _encode_rows
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.network.kernel_checks import require_array, require_int
from vprsnn_export.network.kernel_sums import ANY3, SPIKES, _active_inputs, _row_sum, as_spike_array, compiled
from vprsnn_export.network.parallel import module_slices, run_threads

#: The kernels' scalar parameters (:func:`kernel_scalars`).
Scalars = tuple[np.float32, bool, np.float32, np.float32, np.float32, np.float32, np.float32, bool]


@compiled
def _stdp_window(
    spikes: np.ndarray,  # (B, T, inputs) uint8
    weights: np.ndarray,  # (inputs, neurons) float32, updated in place
    theta: np.ndarray,  # (neurons,) float32
    scalars: Scalars,  # kernel_scalars
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
    beta, wta, pre_keep, post_keep, a_plus, a_minus, w_max, weight_norm = scalars
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
    starts = np.empty(n_inputs + 1, dtype=np.int64)
    members = np.empty(batch * n_inputs, dtype=np.int64)
    ready = False  # this step's lists and currents were made while normalising the last step's weights
    for t in range(timesteps):
        if not ready:
            for b in range(batch):
                n_active[b] = _active_inputs(spikes[b, t], index[b])
                _row_sum(weights, index[b], n_active[b], current[b])
        ready = False
        n_win = n_used = 0
        for b in range(batch):  # row by row: the rows share only sums taken in row order (fired_total, P^T, D)
            row_voltage, row_current, row_fired = voltage[b], current[b], fired[b]
            n_cand = 0
            for j in range(n_neurons):  # branch-free: vectorised
                v = beta * row_voltage[j] + row_current[j]
                candidate = v > theta[j]
                row_fired[j] = candidate
                row_voltage[j] = zero if candidate else v
                n_cand += candidate
            n_winners[b] = 0
            if n_cand > 0:
                for j in range(n_neurons):
                    if row_fired[j]:
                        winners[b, n_winners[b]] = j
                        n_winners[b] += 1
            if n_cand > 0 and wta:  # the first candidate with the largest current fires
                best = winners[b, 0]
                for w in range(n_winners[b]):
                    j = winners[b, w]
                    row_fired[j] = False
                    best = j if row_current[j] > row_current[best] else best
                row_fired[best] = True
                winners[b, 0] = best
                n_winners[b] = 1
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
            n_win = _add_trace(winners[b, : n_winners[b]], win_slot, win_cols, n_win, potentiation, pre_trace[b])
            if row_traced[b]:
                n_used = _add_trace(index[b, : n_active[b]], input_slot, inputs_used, n_used, depression, post_trace[b])
        if np.any(traced) or (weight_norm and not np.all(settled)):  # some column changes
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
                if dividing:  # after the last step the currents it sums go unused
                    following = spikes[:, min(t + 1, timesteps - 1)]
                    _divide_and_sum(weights, scale, following, index, n_active, current, starts, members)
                    ready = True
        win_slot[win_cols[:n_win]] = -1
        input_slot[inputs_used[:n_used]] = -1
    return fired_total


@compiled
def _add_trace(
    keys: np.ndarray, slot: np.ndarray, used: np.ndarray, n_used: int, sums: np.ndarray, trace: np.ndarray
) -> int:
    """sums[slot[k]] += trace (in order) for each key k, a key without a row taking the next one (zeroed) and
    listed in ``used``; returns the rows in use. P^T: keys a row's winners, traces x_b; D: its active inputs, y_b."""
    for k in keys:
        if slot[k] < 0:
            slot[k] = n_used
            used[n_used] = k
            sums[n_used] = 0
            n_used += 1
        row = sums[slot[k]]
        for i in range(trace.size):
            row[i] += trace[i]
    return n_used


@compiled
def _divide_and_sum(
    weights: np.ndarray,  # (inputs, neurons) float32: divided by scale in place
    scale: np.ndarray,  # (neurons,) float32
    spikes: np.ndarray,  # (B, inputs) the next step's input spikes
    index: np.ndarray,  # (B, inputs) out: the next step's active inputs per row
    n_active: np.ndarray,  # (B,) out
    current: np.ndarray,  # (B, neurons) out: the next step's currents, as _row_sum sums them
    starts: np.ndarray,  # (inputs + 1,) scratch
    members: np.ndarray,  # (B inputs,) scratch
) -> None:
    """Column normalisation w_ij <- w_ij / n_j fused with the next step's currents, in one pass over W.

    Each row of W, once divided, is added (still in L1) to the currents of the rows b whose input
    is active next: row b's inputs arrive in increasing order, so its sum from zero makes exactly the
    additions of :func:`_row_sum`.
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
    starts[1:n_inputs] = starts[: n_inputs - 1].copy()
    starts[0] = 0
    current[:] = 0
    for i in range(n_inputs):
        row = weights[i]
        for j in range(n):
            row[j] = row[j] / scale[j]
        for m in range(starts[i], starts[i + 1]):
            sums = current[members[m]]
            for j in range(n):
                sums[j] += row[j]


@compiled
def _stdp_windows(
    limits: np.ndarray,  # (M, B, inputs) int32: bernoulli_limits of each row's firing probabilities
    seeds: np.ndarray,  # (M, B) int64: generator_seeds of each row's presentation seed
    sizes: np.ndarray,  # (M,) int64: rows of module m in this batch (0: it sits the batch out)
    timesteps: int,
    weights: np.ndarray,  # (M, inputs, neurons) float32, updated in place
    theta: np.ndarray,  # (M, neurons) float32
    scalars: Scalars,  # kernel_scalars
    philox: bool,
) -> np.ndarray:
    """One training batch of every module: encode module m's rows (MT19937, or Philox4x32-10 with ``philox``), then
    its :func:`_stdp_window`.

    The modules are independent networks, so each one's window is exactly the single network's;
    returns the spikes per neuron of every module in this batch (M, neurons) float32.
    """
    n_modules, batch, n_inputs = limits.shape
    fired = np.zeros((n_modules, weights.shape[2]), dtype=np.float32)
    spikes = np.empty((batch, timesteps, n_inputs), dtype=np.uint8)
    for m in range(n_modules):
        rows = sizes[m]
        if rows > 0:
            _encode_rows(limits[m, :rows], seeds[m, :rows], timesteps, spikes[:rows], philox)
            fired[m] = _stdp_window(spikes[:rows], weights[m], theta[m], scalars)
    return fired


def stdp_window_kernel(spikes: np.ndarray, weights: np.ndarray, theta: np.ndarray, scalars: Scalars) -> np.ndarray:
    """:func:`_stdp_window` once every array it indexes is checked (InvalidValueError naming it)."""
    k = "STDP window kernel"
    require_array(k, "spikes", spikes, SPIKES, ANY3)
    require_array(k, "weights", weights, (np.float32,), (spikes.shape[2], None), writable=True)
    require_array(k, "theta", theta, (np.float32,), (weights.shape[1],))
    return _stdp_window(spikes, weights, theta, scalars)


def stdp_windows_kernel(
    limits: np.ndarray,
    seeds: np.ndarray,
    sizes: np.ndarray,
    timesteps: int,
    weights: np.ndarray,
    theta: np.ndarray,
    scalars: Scalars,
    philox: bool,
) -> np.ndarray:
    """:func:`_stdp_windows` once every array it indexes is checked (InvalidValueError naming it); ``philox``: the
    encoder's generator is Philox4x32-10, else MT19937."""
    k = "STDP windows kernel"
    require_array(k, "limits", limits, (np.int32,), ANY3)
    n_modules, batch, n_inputs = limits.shape
    require_array(k, "seeds", seeds, (np.int64,), (n_modules, batch))
    require_array(k, "sizes", sizes, (np.int64,), (n_modules,))
    if sizes.size and (sizes.min() < 0 or sizes.max() > batch):
        raise InvalidValueError(f"{k}: sizes must lie in [0, {batch}], got [{sizes.min()}, {sizes.max()}]")
    steps = require_int(k, "timesteps", timesteps, 0)
    require_array(k, "weights", weights, (np.float32,), (n_modules, n_inputs, None), writable=True)
    require_array(k, "theta", theta, (np.float32,), (n_modules, weights.shape[2]))
    return _stdp_windows(limits, seeds, sizes, steps, weights, theta, scalars, bool(philox))


#: Modules one call of the training kernel trains (:func:`stdp_windows`): what an interrupt waits for, per thread.
MODULES_PER_CALL = 8


def kernel_scalars(cfg: Config) -> Scalars:
    """The kernels' scalar parameters: beta, wta, pre_keep = 1 - 1/tau_pre, post_keep = 1 - 1/tau_post, A+, A-,
    w_max (float32) and weight_norm."""
    stdp = cfg.stdp
    keeps = (np.float32(1.0 - 1.0 / stdp.tau_pre), np.float32(1.0 - 1.0 / stdp.tau_post))
    rates = (np.float32(stdp.a_plus), np.float32(stdp.a_minus), np.float32(stdp.w_max))
    return (np.float32(cfg.network.beta), bool(cfg.network.wta), *keeps, *rates, bool(stdp.weight_norm))


def stdp_window(
    weights: torch.Tensor, theta: torch.Tensor, spikes: torch.Tensor, cfg: Config
) -> tuple[torch.Tensor, torch.Tensor] | None:
    """One training batch (B, T, inputs) with plasticity on, compiled: the step loop of ``train.train_batch``
    (STDP eq. 7 summed over the batch in row order; the float32 order: the module docstring).

    Returns (new weights, spikes per neuron in the batch as float32), or ``None`` when the tensors are not float32
    on the CPU: the caller then runs the torch loop. Homeostasis is the caller's.
    """
    if weights.device.type != "cpu" or weights.dtype != torch.float32 or theta.dtype != torch.float32:
        return None
    updated = weights.detach().clone().contiguous()
    fired = stdp_window_kernel(
        as_spike_array(spikes), updated.numpy(), np.ascontiguousarray(theta.detach().numpy()), kernel_scalars(cfg)
    )
    return updated, torch.from_numpy(fired)


def stdp_windows(
    weights: np.ndarray,
    theta: np.ndarray,
    limits: np.ndarray,
    seeds: np.ndarray,
    sizes: np.ndarray,
    cfg: Config,
    *,
    threads: int = 1,
) -> np.ndarray:
    """One training batch of M independent modules, compiled: :func:`stdp_window` for each, side by side.

    ``weights`` (M, inputs, n) float32 C-contiguous are updated in place; ``theta`` (M, n) float32;
    module m's batch is its first ``sizes[m]`` rows of ``limits`` (M, B, inputs) int32
    (:func:`bernoulli_limits`) and ``seeds`` (M, B) (:func:`generator_seeds`), encoded inside the
    kernel exactly as :func:`bernoulli_spikes` encodes them with the config's generator, so module m's weights are
    those of ``stdp_window`` on its own batch bit for bit. Each kernel call trains a contiguous slice of at most
    :data:`MODULES_PER_CALL` modules, on ``threads`` Python threads (:func:`~vprsnn_export.network.parallel.run_threads`:
    an interrupt waits for the slices in flight only, not the whole batch; at 27k places a thread's half of a batch
    is 135 modules, ~30 s). Returns the spikes per neuron (M, n) float32.
    """
    scalars = kernel_scalars(cfg)
    philox = cfg.encoder.generator == "philox"
    timesteps = int(cfg.training_encoder.timesteps)
    sizes = np.ascontiguousarray(sizes, dtype=np.int64)

    parts = module_slices(len(limits), max(threads, -(-len(limits) // MODULES_PER_CALL)))
    tasks = [
        partial(stdp_windows_kernel, limits[p], seeds[p], sizes[p], timesteps, weights[p], theta[p], scalars, philox)
        for p in parts
    ]
    return np.concatenate(run_threads(tasks, threads))
