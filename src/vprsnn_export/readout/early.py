"""Early decision: stop a query when its outcome is settled, as a readout rule a chip can run.

Every output neuron j votes for one place (its Standard assignment, ``A = standard_assignment(S~)``: a one-hot row,
or none for a neuron silent in calibration or silenced by the region regularisation). A chip keeps one vote counter
per place and adds A_j to it on each spike of j. After t steps

    V_l(t) = sum_{t' < t} sum_j z_j[t'] A_jl                     (z: the raster, WTA applied)

Each step adds at most c = sum over WTA groups g of max_{j in g, l} A_jl to any one place (one spike per group per
step under the hard WTA: c = 1 with one WTA over the ensemble, the number of modules with one per module). Two stop
rules (``config.early``), the earliest that fires wins:

* **margin**: stop at the first t with  V_(1)(t) - V_(2)(t) > (T - t) c   (leader minus runner-up); the leader can
  then no longer be overtaken nor tied, so the Standard decision at t is the one at T;
* **spikes** = K > 0: stop at the first t with  sum_{t' < t} sum_j z_j[t'] >= K.

T_q = that t (the number of steps run), or T when no rule fires. The query's counts are those of its first T_q steps,
c_j = sum_{t < T_q} z_j[t], and every readout (W+Prob, aggregation) runs on them. The raster is a pure function of the
spike train, bit for bit the same in every backend (the integer simulator, ONNX, the files read back), so the stop step
and the decision computed from any backend's raster are the same: the rule needs no second implementation per backend.
Running only the first T_q steps gives the same counts (state isolation: a step never depends on later ones).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from vprsnn_export.config import Config, EarlyConfig, wta_group
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.network.runs import SpikeRun

from .assignment import standard_assignment
from .regions import calibrated_half, ensemble_layout

#: Queries whose (steps, places) vote trajectories are held at once.
CHUNK = 16


@dataclass(frozen=True)
class EarlyDecision:
    """Per query: the steps run T_q (N,) and the output spike counts of those steps (N, neurons)."""

    steps: np.ndarray
    counts: np.ndarray


def is_off(rule: EarlyConfig) -> bool:
    """Whether no stop rule is enabled (every query runs all T steps)."""
    return not rule.margin and rule.spikes <= 0


def step_bound(assignment: np.ndarray, group: int) -> float:
    """c = sum over WTA groups of the largest entry of A among the group's neurons: the most one step adds to a place."""
    a = np.asarray(assignment, dtype=np.float64)
    if a.ndim != 2 or group < 1 or a.shape[0] % group:
        raise InvalidValueError(f"assignment (neurons, places) must hold whole WTA groups of {group}, got {a.shape}")
    return 0.0 if a.size == 0 else float(a.reshape(a.shape[0] // group, group * a.shape[1]).max(axis=1).sum())


def _raster(raster: object) -> np.ndarray:
    arr = np.asarray(raster)
    if arr.ndim != 3 or arr.dtype != np.bool_:
        raise InvalidValueError(f"raster must be (N, T, neurons) bool, got {arr.dtype} of shape {arr.shape}")
    return arr


def first_true(flags: np.ndarray, default: int) -> np.ndarray:
    """Per row of a (N, T) bool array: 1 + the first index that is True (steps run to see it), else ``default``."""
    return np.where(flags.any(axis=1), flags.argmax(axis=1) + 1, default).astype(np.int64)


def margin_stops(raster: np.ndarray, assignment: np.ndarray, group: int) -> np.ndarray:
    """T_q of the margin rule: the first t with V_(1)(t) - V_(2)(t) > (T - t) c, else T (the module docstring)."""
    n, timesteps, neurons = raster.shape
    a = np.asarray(assignment, dtype=np.float64)
    if a.shape[0] != neurons or a.shape[1] < 1:
        raise InvalidValueError(f"assignment must be ({neurons}, places >= 1), got shape {a.shape}")
    remaining = (timesteps - np.arange(1, timesteps + 1)) * step_bound(a, group)  # (T - t) c after t = 1..T steps
    stops = np.empty(n, dtype=np.int64)
    for start in range(0, n, CHUNK):  # a (chunk, T, places) trajectory at a time
        part = raster[start : start + CHUNK]
        q, t, j = np.nonzero(part)
        increments = np.zeros((part.shape[0], timesteps, a.shape[1]), dtype=np.float64)
        np.add.at(increments, (q, t), a[j])
        votes = np.cumsum(increments, axis=1)
        top = np.partition(votes, -2, axis=2)[:, :, -2:] if a.shape[1] > 1 else np.pad(votes, ((0, 0), (0, 0), (1, 0)))
        stops[start : start + CHUNK] = first_true(top[:, :, 1] - top[:, :, 0] > remaining, timesteps)
    return stops


def spike_stops(raster: np.ndarray, spikes: int) -> np.ndarray:
    """T_q of the spike-count rule: the first t whose steps hold >= ``spikes`` output spikes, else T."""
    emitted = np.cumsum(raster.sum(axis=2, dtype=np.int64), axis=1)
    return first_true(emitted >= spikes, raster.shape[1])


def stop_steps(raster: object, assignment: np.ndarray, group: int, rule: EarlyConfig) -> np.ndarray:
    """T_q per query under ``rule``: the earliest of the enabled rules (T for all when both are off)."""
    z = _raster(raster)
    steps = np.full(z.shape[0], z.shape[1], dtype=np.int64)
    if rule.margin:
        steps = np.minimum(steps, margin_stops(z, assignment, group))
    if rule.spikes > 0:
        steps = np.minimum(steps, spike_stops(z, rule.spikes))
    return steps


def counts_until(raster: object, steps: np.ndarray) -> np.ndarray:
    """c_j = sum_{t < T_q} z_j[t] per query: (N, neurons) int64."""
    z = _raster(raster)
    used = np.arange(z.shape[1])[None, :] < np.asarray(steps)[:, None]
    return np.einsum("ntj,nt->nj", z, used, dtype=np.int64)


def early_decision(raster: object, assignment: np.ndarray, group: int, rule: EarlyConfig) -> EarlyDecision:
    """The stop step and the counts of the steps run, per query (the rule of the module docstring)."""
    steps = stop_steps(raster, assignment, group, rule)
    return EarlyDecision(steps=steps, counts=counts_until(raster, steps))


def early_in_chunks(
    rasters: Callable[[int, int], np.ndarray],
    n_queries: int,
    assignment: np.ndarray,
    group: int,
    rule: EarlyConfig,
    chunk: int = 64,
) -> EarlyDecision:
    """:func:`early_decision` over ``rasters(start, stop)`` (the recorded raster of those queries), ``chunk`` at a
    time, so that a route's rasters never have to be held at once."""
    parts = [
        early_decision(rasters(a, min(a + chunk, n_queries)), assignment, group, rule)
        for a in range(0, n_queries, chunk)
    ]
    if not parts:
        return EarlyDecision(np.zeros(0, np.int64), np.zeros((0, np.asarray(assignment).shape[0]), np.int64))
    return EarlyDecision(np.concatenate([p.steps for p in parts]), np.concatenate([p.counts for p in parts]))


def vote_matrix(calibration: np.ndarray, cfg: Config) -> np.ndarray:
    """A = Standard assignment of the readout's S~ (an ensemble's region regularisation applied, silenced rows 0)."""
    return standard_assignment(calibrated_half(calibration, ensemble_layout(cfg, np.shape(calibration)[1]))[0])


def early_queries(
    run: Callable[..., SpikeRun],
    spikes: torch.Tensor,
    calibration: np.ndarray,
    cfg: Config,
    *,
    keep_raster: bool = False,
    isolated: bool | None = None,
) -> tuple[list[SpikeRun], EarlyDecision]:
    """``config.early`` in one pass: each chunk of queries run once with its raster (``run(part, record=True)``)
    and decided on it (:func:`early_decision`); the chunk runs come back beside the decision (their rasters only
    with ``keep_raster``: a route's rasters are never held at once otherwise), so a caller that also needs the
    whole presentations (candidates, saturations) runs nothing twice. The rule must be on. ``isolated``: whether
    the run keeps state isolation (None: the config's); the rule needs it."""
    if not (cfg.network.state_isolation if isolated is None else isolated):
        raise InvalidValueError("config.early needs state isolation (each query run on its own from V = 0)")
    votes = vote_matrix(calibration, cfg)
    group = wta_group(cfg, votes.shape[0])
    runs: list[SpikeRun] = []

    def raster(start: int, stop: int) -> np.ndarray:
        part = run(spikes[start:stop], record=True)
        if part.raster is None:
            raise InvalidValueError("the early decision needs the backend's raster (record=True)")
        runs.append(part if keep_raster else dataclasses.replace(part, raster=None))
        return part.raster.numpy()

    return runs, early_in_chunks(raster, int(spikes.shape[0]), votes, group, cfg.early)


def early_run(
    run: Callable[..., SpikeRun],
    spikes: torch.Tensor,
    calibration: np.ndarray,
    cfg: Config,
    *,
    isolated: bool | None = None,
) -> EarlyDecision | None:
    """``config.early``'s decision for the queries ``spikes`` on a backend (:func:`early_queries`, chunk by chunk:
    the rasters of a whole route need not fit in memory); None when the rule is off."""
    return None if is_off(cfg.early) else early_queries(run, spikes, calibration, cfg, isolated=isolated)[1]
