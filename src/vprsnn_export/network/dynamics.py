"""Float discrete LIF dynamics with hard winner-take-all (paper eq. 1-4, as the issue fixes them).

Per time step t, for a batch of presentations (rows) and neurons j:

    I_j[t] = sum_i w_ij s_i[t]
    V_j[t] = beta V_j[t-1] + I_j[t]
    C[t]   = {j : V_j[t] > theta_j}                       (candidates)
    WTA on:  S_j[t] = 1 for the one j in C[t] with the largest I_j[t]
             (ties: lowest index); nothing fires if C[t] is empty.
             In an ensemble of modules (:mod:`vprsnn_export.network.modules`) this holds
             within each WTA group (:func:`vprsnn_export.config.wta_group`): all
             neurons (network.wta_scope = ensemble) or each module's n neurons
    WTA off: S_j[t] = 1 for every j in C[t]
    V_j[t] <- 0 for every j in C[t]                        (reset to zero)

State is zeroed at t = 0 of every presentation (state isolation); with isolation off the presentations run
one after another and V carries over. The input currents of all steps are one matrix product; only the
recurrence over t is a loop, vectorised over presentations and neurons.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ..arguments import real_array, require_type
from ..config import Config, wta_group
from ..device import check_device
from ..errors import InvalidValueError
from ..resources import LOWER_RUN, check_memory, run_need
from .dynamics_kernel import QUERY_CHUNK, float_run
from .runs import SpikeRun, run_in_chunks


def check_run_memory(cfg: Config, what: str, **sizes: Any) -> None:
    """InvalidValueError (one line) when a run would not fit in the memory limit (:mod:`~vprsnn_export.resources`):
    :func:`~vprsnn_export.resources.run_need` of ``sizes`` with the sizes of ``cfg`` (T, D, rate scale) and
    :data:`QUERY_CHUNK` presentations run at once."""
    timesteps, inputs, rate = cfg.encoder.timesteps, cfg.network.n_inputs, cfg.encoder.rate_scale
    need = run_need(timesteps=timesteps, n_inputs=inputs, chunk=QUERY_CHUNK, rate_scale=rate, **sizes)
    check_memory(need, what, LOWER_RUN)


def wta_step(
    voltage: torch.Tensor, current: torch.Tensor, theta: torch.Tensor, beta: float, wta: bool, group: int | None = None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One step: V = beta V + I; C = {V > theta}; S = winner(C) or C; V[C] = 0.

    The winner is taken within each group of ``group`` consecutive neurons (``None``: all
    neurons are one group). Returns (new voltage, spikes as bool (B, neurons), candidates
    as bool (B, neurons)); any leading dimensions (M, B, neurons) are kept (``theta`` broadcasts).
    """
    voltage = beta * voltage + current
    candidates = voltage > theta
    if not wta:
        return voltage.masked_fill(candidates, 0.0), candidates, candidates
    *lead, n_neurons = candidates.shape
    size = n_neurons if group is None else group
    grouped = candidates.reshape(*lead, n_neurons // size, size)
    masked = current.reshape(grouped.shape).masked_fill(~grouped, float("-inf"))
    winner = masked.argmax(dim=-1, keepdim=True)  # first index on ties
    spikes = torch.zeros_like(grouped).scatter_(-1, winner, grouped.any(dim=-1, keepdim=True))
    return voltage.masked_fill(candidates, 0.0), spikes.reshape(*lead, n_neurons), candidates


def input_currents(spikes: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """I[n, t, j] = sum_i s[n, t, i] w_ij for spikes (N, T, inputs) -> (N, T, neurons)."""
    return torch.matmul(spikes.to(weights.dtype), weights)


def run_network(
    spikes: torch.Tensor,
    weights: torch.Tensor,
    theta: torch.Tensor,
    *,
    beta: float,
    wta: bool = True,
    state_isolation: bool = True,
    record: bool = False,
    compiled: bool = True,
    group: int | None = None,
) -> SpikeRun:
    """Present N spike trains (N, T, inputs) to the network with plasticity off.

    ``group``: neurons per WTA group (one module of an ensemble); ``None``: one group.

    On the CPU (float32 weights) the compiled event-driven kernel runs it (:func:`.dynamics_kernel.float_run`: the
    currents summed in increasing input order, the same on every CPU; the torch loop agrees to float32 rounding);
    ``compiled=False`` (and any GPU) runs the torch loop below, one matmul for all currents and a loop over t. The
    spikes may live on the CPU; they are moved to ``weights.device`` chunk by chunk.
    """
    check_network(spikes, weights, theta)
    if compiled and weights.device.type == "cpu" and weights.dtype == torch.float32:
        run = float_run(
            spikes, weights, theta, beta=beta, wta=wta, isolation=state_isolation, record=record, group=group
        )
        return run if state_isolation else SpikeRun(run.counts, run.candidates_per_step, run.raster, None)
    device = weights.device
    n_presentations, timesteps, _ = spikes.shape
    n_neurons = weights.shape[1]
    if not state_isolation:  # all presentations form one stream, in order (the spillover ablation)
        stream = spikes.reshape(1, n_presentations * timesteps, spikes.shape[2])
        whole = run_network(stream, weights, theta, beta=beta, wta=wta, record=True, group=group)
        assert whole.raster is not None and whole.candidates_per_step is not None  # recorded above
        stepped = whole.raster.reshape(n_presentations, timesteps, -1)
        per_step = whole.candidates_per_step.reshape(n_presentations, timesteps)
        return SpikeRun(stepped.sum(dim=1, dtype=torch.int64), per_step, stepped if record else None)
    counts = torch.zeros((n_presentations, n_neurons), dtype=torch.int64)
    n_candidates = torch.zeros((n_presentations, timesteps), dtype=torch.int32)
    raster = torch.zeros((n_presentations, timesteps, n_neurons), dtype=torch.bool) if record else None
    final_voltage = torch.zeros((n_presentations, n_neurons), dtype=weights.dtype)
    for start in range(0, n_presentations, QUERY_CHUNK):
        rows = slice(start, start + QUERY_CHUNK)
        currents = input_currents(spikes[rows].to(device), weights)  # (chunk, T, neurons)
        voltage = torch.zeros((len(currents), n_neurons), dtype=weights.dtype, device=device)
        chunk_counts = torch.zeros_like(voltage, dtype=torch.int64)
        chunk_candidates = torch.zeros(currents.shape[:2], dtype=torch.int32, device=device)
        chunk_raster = torch.zeros_like(currents, dtype=torch.bool) if raster is not None else None
        for t in range(timesteps):
            voltage, fired, candidates = wta_step(voltage, currents[:, t], theta, beta, wta, group)
            chunk_counts += fired
            chunk_candidates[:, t] = candidates.sum(dim=1, dtype=torch.int32)
            if chunk_raster is not None:
                chunk_raster[:, t] = fired
        counts[rows], n_candidates[rows] = chunk_counts.cpu(), chunk_candidates.cpu()
        final_voltage[rows] = voltage.cpu()
        if raster is not None and chunk_raster is not None:
            raster[rows] = chunk_raster.cpu()
    return SpikeRun(counts, n_candidates, raster, final_voltage)


def check_network(spikes: torch.Tensor | None, weights: torch.Tensor, theta: torch.Tensor) -> None:
    """Weights (inputs, neurons), thresholds (neurons,) and spikes (N, T, inputs); InvalidValueError naming the one
    that does not fit (a short threshold vector would broadcast or be read past its end)."""
    for name, value in (("weights", weights), ("thresholds", theta), ("spikes", spikes)):
        if value is not None and not isinstance(value, torch.Tensor):
            raise InvalidValueError(f"{name} must be a torch tensor, got {type(value).__name__}")
    if weights.ndim != 2:
        raise InvalidValueError(f"weights must be (inputs, neurons), got shape {tuple(weights.shape)}")
    if tuple(theta.shape) != (weights.shape[1],):
        raise InvalidValueError(
            f"thresholds have shape {tuple(theta.shape)}, expected ({weights.shape[1]},): one per neuron"
        )
    if spikes is not None and (spikes.ndim != 3 or spikes.shape[2] != weights.shape[0]):
        raise InvalidValueError(f"spikes must be (N, T, {weights.shape[0]}), got shape {tuple(spikes.shape)}")


@dataclass
class FloatNetwork:
    """The float reference network: float32 weights and thresholds on a device (a :class:`~vprsnn_export.network.runs.Backend`)."""

    weights: torch.Tensor
    thresholds: torch.Tensor
    cfg: Config
    name: str = "float"
    progress: bool = False  # a bar on stderr over the chunks of state-isolated presentations

    def __post_init__(self) -> None:
        require_type("cfg", self.cfg, Config)
        check_network(None, self.weights, self.thresholds)
        group = self.cfg.network.n_neurons
        if self.weights.shape[1] == 0 or self.weights.shape[1] % group:
            raise InvalidValueError(
                f"weights: {self.weights.shape[1]} neurons are not whole modules of network.n_neurons = {group}"
            )

    @classmethod
    def from_arrays(
        cls, weights: np.ndarray, thresholds: np.ndarray, cfg: Config, device: torch.device
    ) -> FloatNetwork:
        where = check_device("device", device)
        return cls(
            torch.as_tensor(real_array("weights", weights), dtype=torch.float32).to(where),
            torch.as_tensor(real_array("thresholds", thresholds), dtype=torch.float32).to(where),
            cfg,
        )

    def run(self, spikes: torch.Tensor, *, record: bool = False, state_isolation: bool | None = None) -> SpikeRun:
        isolation = self.cfg.network.state_isolation if state_isolation is None else state_isolation

        def whole(part: torch.Tensor) -> SpikeRun:
            return run_network(
                part,
                self.weights,
                self.thresholds,
                beta=self.cfg.network.beta,
                wta=self.cfg.network.wta,
                state_isolation=isolation,
                record=record,
                group=wta_group(self.cfg, int(self.weights.shape[1])),
            )

        # chunks only when isolated: each presentation then starts from V = 0 (run_in_chunks)
        return run_in_chunks(whole, spikes, chunk=QUERY_CHUNK, progress=self.progress and isolation, desc=self.name)

    def counts(self, spikes: torch.Tensor) -> torch.Tensor:
        """Output spike counts (N, neurons): the ``run_counts`` callable of calibration."""
        return self.run(spikes).counts
