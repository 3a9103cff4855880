"""The fast integer simulator: the fixed-point model of :mod:`export.model`, bit for bit.

Per chunk of presentations (state isolation) or per presentation (one stream):

1. Currents of all steps at once, already shifted: A[t, n, j] = (sum_i s[n, t, i] q_ij) << shift.
   One float32 matmul computes them exactly: every term is a non-negative integer
   multiple of 2**shift and every partial sum is bounded by the total
   n_inputs (2**bits - 1) 2**shift (784 * 255 * 64 < 2**24), so no rounding can
   occur. The bound is checked from the model; above 2**24, and always on CUDA (where
   float32 matmuls may run in TF32), the matmul runs in float64 (exact below 2**53).
   The result is cast to int32.
2. The recurrence over t: one Python loop of T steps, each a handful of int64 tensor
   ops over (presentations, neurons):

       V = (V (4096 - dv)) >> 12             trunc toward zero (V >= 0, see below)
       V = V + A[t];  saturations += #{V > Vmax};  V = min(V, Vmax)
       C = {j : V_j > theta_j << shift}
       WTA on:  winner = argmax_j of (a_j m_j if j in C else -1), first index on ties;
                it spikes iff C is not empty
       WTA off: every j in C spikes
       V[C] = 0

Invariants that make the fast path exact: weights are unsigned and the state starts
and resets at 0, so V >= 0 always (floor = trunc toward zero, no negative clip); after
every step V_j <= theta_j << shift (a neuron above it is a candidate and is reset), so
the next voltage before clipping is at most theta_j << shift + A[t, n, j]. When that
bound is <= Vmax for every neuron and step of a chunk, saturation is impossible there
and the clip is skipped; otherwise every clip is counted.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
import torch

from vprsnn_export.arguments import require_type
from vprsnn_export.config import wta_group
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import DECAY_BITS, FixedPointModel
from vprsnn_export.network.runs import SpikeRun, run_in_chunks

from .intsim_kernel import KernelWeights, integer_run, kernel_weights

QUERY_CHUNK = 128  # presentations per chunk: bounds the (T, chunk, neurons) current tensor
FLOAT32_EXACT = 1 << 24  # float32 holds every integer below 2**24 exactly


def matmul_dtype(model: FixedPointModel, device: torch.device) -> torch.dtype:
    """float32 when every current sum is below 2**24 on the CPU; float64 otherwise (exact below 2**53, beyond any
    model that fits in memory: 2**47 / 255 inputs), and on CUDA, where float32 matmuls may run in TF32 (10-bit
    mantissa). The largest current: max_j sum_i q_ij << shift (every input spiking)."""
    bound = int(model.weight_mantissa.astype(np.int64).sum(axis=0).max()) << model.voltage_shift
    return torch.float32 if bound < FLOAT32_EXACT and device.type == "cpu" else torch.float64


@dataclass(frozen=True)
class PreparedModel:
    """The model's integers as tensors on one device, in the form the loop uses."""

    weights: torch.Tensor  # (inputs, neurons) q_ij << shift, float32 or float64 (exact, see matmul_dtype)
    threshold: torch.Tensor  # (neurons,) int64 theta_j << shift
    multipliers: torch.Tensor | None  # (neurons,) int64 m_j; None when all equal (the WTA then compares a_j)
    keep: int  # 4096 - dv
    limit: int  # 2**23 - 1
    shift: int
    wta: bool
    group: int  # neurons per WTA group: one module of an ensemble (network.n_neurons)
    mantissas: KernelWeights  # (inputs, neurons) the unshifted q_ij as the compiled CPU kernel reads them


def prepare(model: FixedPointModel, device: torch.device) -> PreparedModel:
    """The model on ``device``, once the arrays the simulator indexes are checked: mantissas (inputs, neurons) and
    thresholds and multipliers (neurons,), all integers, neurons in whole WTA groups (InvalidValueError naming the
    array otherwise)."""
    arrays = {name: getattr(model, name) for name in ("weight_mantissa", "threshold", "scale_multiplier")}
    for name, array in arrays.items():
        if not isinstance(array, np.ndarray) or not np.issubdtype(array.dtype, np.integer):
            raise InvalidValueError(f"fixed-point model: {name} must be an integer numpy array")
    if model.weight_mantissa.ndim != 2:
        raise InvalidValueError(f"fixed-point model: weight_mantissa has shape {model.weight_mantissa.shape}, not 2-D")
    for name in ("threshold", "scale_multiplier"):
        if arrays[name].shape != (model.n_neurons,):
            raise InvalidValueError(
                f"fixed-point model: {name} has shape {arrays[name].shape}, expected ({model.n_neurons},)"
            )
    group = model.config.network.n_neurons
    if model.n_neurons == 0 or model.n_neurons % group:
        raise InvalidValueError(
            f"fixed-point model: {model.n_neurons} neurons are not whole modules of network.n_neurons = {group}"
        )
    multipliers = torch.as_tensor(model.scale_multiplier.astype(np.int64), device=device)
    return PreparedModel(
        weights=torch.as_tensor(
            model.weight_mantissa.astype(np.int64) << model.voltage_shift,
            dtype=matmul_dtype(model, device),
            device=device,
        ),
        threshold=torch.as_tensor(model.threshold.astype(np.int64) << model.voltage_shift, device=device),
        multipliers=None if bool((multipliers == multipliers[0]).all()) else multipliers,
        keep=(1 << DECAY_BITS) - model.decay_dv,
        limit=model.voltage_limit,
        shift=model.voltage_shift,
        wta=model.config.network.wta,
        group=wta_group(model.config, model.n_neurons),
        mantissas=kernel_weights(model.weight_mantissa),
    )


@dataclass
class IntegerNetwork:
    """A fixed-point model prepared for the fast simulator on one device; ``saturations`` accumulates over every
    call (e.g. all calibration runs)."""

    model: FixedPointModel
    device: torch.device | None = None
    saturations: int = 0
    name: str = "integer simulator"
    progress: bool = False  # a bar on stderr over the chunks of state-isolated presentations
    prepared: PreparedModel = field(init=False, repr=False)

    def __post_init__(self) -> None:
        require_type("model", self.model, FixedPointModel)
        self.device = torch.device("cpu") if self.device is None else torch.device(self.device)
        self.prepared = prepare(self.model, self.device)

    def run(self, spikes: torch.Tensor, *, record: bool = False, state_isolation: bool | None = None) -> SpikeRun:
        """Present N spike trains (N, T, inputs) of 0/1 uint8 (the float path's very tensors)."""
        isolation = self.model.config.network.state_isolation if state_isolation is None else state_isolation
        if spikes.ndim != 3 or spikes.shape[2] != self.model.n_inputs:
            shape = f"(N, T, {self.model.n_inputs})"
            raise InvalidValueError(f"spikes: expected spikes of shape {shape}, got {tuple(spikes.shape)}")
        if spikes.dtype not in (torch.uint8, torch.bool):
            raise InvalidValueError(f"spikes: expected uint8 or bool spikes, got {spikes.dtype}")
        if spikes.numel() and spikes.dtype == torch.uint8 and int(spikes.max()) > 1:
            raise InvalidValueError("spikes: spikes must be 0 or 1")
        whole = functools.partial(run_prepared, self.prepared, isolation=isolation, record=record)
        # chunks only when isolated: each presentation then starts from V = 0 (run_in_chunks)
        run = run_in_chunks(whole, spikes, chunk=QUERY_CHUNK, progress=self.progress and isolation, desc=self.name)
        self.saturations += run.saturations
        return run

    def counts(self, spikes: torch.Tensor) -> torch.Tensor:
        """Output spike counts (N, neurons): the ``run_counts`` callable of trainer.calibrate."""
        return self.run(spikes).counts


def simulate(
    model: FixedPointModel,
    spikes: torch.Tensor,
    *,
    record: bool = False,
    state_isolation: bool | None = None,
    device: torch.device | None = None,
) -> SpikeRun:
    """Run the fixed-point model on spike trains (N, T, inputs) uint8."""
    return IntegerNetwork(model, device).run(spikes, record=record, state_isolation=state_isolation)


def shifted_currents(spikes: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """A[t, n, j] = sum_i s[n, t, i] (q_ij << shift) as int32, laid out (T, N, neurons) for the loop."""
    n, timesteps, n_inputs = spikes.shape
    dense = torch.empty((timesteps, n, n_inputs), dtype=weights.dtype, device=weights.device)
    dense.copy_(spikes.to(weights.device).transpose(0, 1))
    return torch.matmul(dense.view(timesteps * n, n_inputs), weights).view(timesteps, n, -1).to(torch.int32)


@dataclass
class ChunkRun:
    """What :func:`recur` returns for one chunk (laid out time-major)."""

    voltage: torch.Tensor  # (B, neurons) int64 after the last step
    counts: torch.Tensor  # (B, neurons) int64
    candidates: torch.Tensor  # (T, B) int32
    raster: torch.Tensor | None  # (T, B, neurons) bool
    saturations: int
    max_current: int  # shifted


def run_prepared(
    prep: PreparedModel, spikes: torch.Tensor, *, isolation: bool, record: bool, compiled: bool = True
) -> SpikeRun:
    """The whole run: on the CPU the compiled event-driven kernel (:func:`vprsnn_export.targets.intsim_kernel.integer_run`,
    bit-identical); otherwise (or ``compiled=False``) chunks of QUERY_CHUNK presentations in parallel
    (isolation), or one presentation at a time carrying V, through :func:`recur`."""
    if compiled and prep.threshold.device.type == "cpu":
        multipliers = None if prep.multipliers is None else prep.multipliers.numpy()
        return integer_run(
            spikes, prep.mantissas, prep.threshold.numpy(), multipliers, shift=prep.shift, keep=prep.keep,
            limit=prep.limit, wta=prep.wta, isolation=isolation, record=record, group=prep.group,
        )  # fmt: skip
    n, timesteps, _ = spikes.shape
    n_neurons = prep.threshold.shape[0]
    counts = torch.zeros((n, n_neurons), dtype=torch.int64)
    n_candidates = torch.zeros((n, timesteps), dtype=torch.int32)
    raster = torch.zeros((n, timesteps, n_neurons), dtype=torch.bool) if record else None
    final_voltage = torch.zeros((n, n_neurons), dtype=torch.int64)
    saturations = max_current = 0
    voltage: torch.Tensor | None = None  # the stream's, carried (None: zeros)
    chunk = QUERY_CHUNK if isolation else 1
    for start in range(0, n, chunk):
        stop = min(start + chunk, n)
        step = recur(prep, shifted_currents(spikes[start:stop], prep.weights), voltage, record)
        voltage = None if isolation else step.voltage
        counts[start:stop] = step.counts.cpu()
        n_candidates[start:stop] = step.candidates.T.cpu()
        final_voltage[start:stop] = step.voltage.cpu()
        saturations += step.saturations
        max_current = max(max_current, step.max_current >> prep.shift)
        if raster is not None and step.raster is not None:
            raster[start:stop] = step.raster.transpose(0, 1).cpu()
    return SpikeRun(counts, n_candidates, raster, final_voltage, saturations, max_current)


def recur(prep: PreparedModel, currents: torch.Tensor, voltage: torch.Tensor | None, record: bool) -> ChunkRun:
    """The loop over t (module docstring, step 2) for shifted currents (T, B, neurons) int32, starting from voltage
    (B, neurons) int64 or zeros (None); a WTA winner fires iff its score is >= 0 (winners gathered after the loop)."""
    timesteps, batch, n_neurons = currents.shape
    device = currents.device
    threshold, limit, multipliers = prep.threshold, prep.limit, prep.multipliers
    peak = currents.amax(dim=(0, 1)).to(torch.int64) if timesteps and batch else torch.zeros_like(threshold)
    may_saturate = bool((peak + threshold > limit).any())
    voltage = torch.zeros((batch, n_neurons), dtype=torch.int64, device=device) if voltage is None else voltage.clone()
    candidates = torch.empty((batch, n_neurons), dtype=torch.bool, device=device)
    n_candidates = torch.empty((timesteps, batch), dtype=torch.int64, device=device)
    score_dtype = torch.int32 if multipliers is None else torch.int64
    minus_one = torch.tensor(-1, dtype=score_dtype, device=device)
    score = torch.empty((batch, n_neurons), dtype=score_dtype, device=device)
    best: list[torch.Tensor] = []  # per step: (B, modules) best score
    winner: list[torch.Tensor] = []  # per step: (B, modules) winning neuron index
    group_offsets = torch.arange(0, n_neurons, prep.group, device=device)
    counts = torch.zeros((batch, n_neurons), dtype=torch.int64, device=device)
    raster = torch.zeros((timesteps, batch, n_neurons), dtype=torch.bool, device=device) if record else None
    saturations = torch.zeros((), dtype=torch.int64, device=device)
    for t in range(timesteps):
        current = currents[t]
        voltage.mul_(prep.keep).bitwise_right_shift_(DECAY_BITS).add_(current)
        if may_saturate:
            saturations += (voltage > limit).sum()
            voltage.clamp_(max=limit)
        torch.gt(voltage, threshold, out=candidates)
        torch.sum(candidates, dim=1, out=n_candidates[t])
        if prep.wta:
            scored = current if multipliers is None else torch.mul(current, multipliers, out=score)
            torch.where(candidates, scored, minus_one, out=score)
            value, index = score.view(batch, -1, prep.group).max(dim=2)  # one winner per module
            best.append(value)
            winner.append(index + group_offsets)
        else:
            counts.add_(candidates)
            if raster is not None:
                raster[t] = candidates
        voltage.masked_fill_(candidates, 0)
    if prep.wta and timesteps:
        fired, winners = torch.stack(best) >= 0, torch.stack(winner)  # (T, B, modules)
        counts.scatter_add_(
            1, winners.transpose(0, 1).reshape(batch, -1), fired.transpose(0, 1).reshape(batch, -1).long()
        )
        if raster is not None:
            raster.scatter_(2, winners, fired)
    return ChunkRun(voltage, counts, n_candidates.to(torch.int32), raster, int(saturations), int(peak.max()))


def step_agreement(raster_a: torch.Tensor, raster_b: torch.Tensor) -> dict[str, float]:
    """How often two networks make the same decision on the same spike trains.

    all_steps: fraction of (presentation, step) where both emit exactly the same spikes
    (with WTA: the same winner, or both silent); active_steps: the same fraction over
    the steps where at least one of them spikes.
    """
    same = (raster_a == raster_b).all(dim=2)
    active = raster_a.any(dim=2) | raster_b.any(dim=2)
    n_active = int(active.sum())
    return {
        "all_steps": float(same.float().mean()),
        "active_steps": float((same & active).sum()) / n_active if n_active else 1.0,
        "n_steps": int(same.numel()),
        "n_active_steps": n_active,
    }
