"""What one query costs: input spikes, synaptic events, neuron updates and steps, beside the template matcher.

A chip's energy and latency per query scale with the synaptic events it delivers and the time
steps it runs (docs/targets.md, "Cost per query"). For query q with spike train s[q, t, i]
(N, T, I) presented for T_q <= T steps (T_q = T unless an early decision stops it,
:mod:`vprsnn_export.readout.early`) to a layer of J neurons:

    input spikes      S_q = sum_{t < T_q} sum_i s[q, t, i]
    synaptic events   E_q = sum_{t < T_q} sum_i s[q, t, i] f_i           f_i = fan-out of input i
    neuron updates    U_q = T_q J
    template MACs     C_q = nnz(x_q) L                                     (cosine nearest neighbour)

Every input is wired to every neuron of the ensemble (weights (I, M n)), so f_i = J = M n: with one
WTA over the ensemble every input spike reaches all M n neurons, and with ``wta_scope = module`` too
(each module still sees every input). A per-input fan-out (the non-zero weights of row i, what a chip
stores) can be given instead. The template matcher (the no-learning ceiling, ``evaluate --baseline``'s
"cosine") holds L I weights and spends one multiply-add per non-zero input x_q,i and place.

Pure numpy, vectorised over queries and steps.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.io.serial import JsonDataclass

CHUNK = 64  # queries whose spikes are widened to int64 at once for a per-input fan-out


@dataclass(frozen=True)
class CostSummary(JsonDataclass):
    """The means over queries of a :class:`QueryCost` (the JSON and the printed line)."""

    queries: int
    steps: float
    input_spikes: float
    synaptic_events: float
    neuron_updates: float
    template_macs: float
    snn_weights: int
    template_weights: int

    @property
    def event_ratio(self) -> float:
        """Synaptic events per template multiply-add, E / C (inf when the template does nothing)."""
        return self.synaptic_events / self.template_macs if self.template_macs > 0 else float("inf")

    def line(self) -> str:
        """One printed line: ``events per query: SNN ... vs template ...``."""
        return (
            f"events per query: SNN {self.synaptic_events:,.0f} synaptic events ({self.input_spikes:,.0f} input "
            f"spikes x fan-out, {self.steps:.0f} steps, {self.neuron_updates:,.0f} neuron updates) vs template "
            f"{self.template_macs:,.0f} multiply-adds ({self.event_ratio:.1f}x); weights held "
            f"{self.snn_weights:,} vs {self.template_weights:,}"
        )


@dataclass(frozen=True)
class QueryCost:
    """Per-query cost arrays (N,) int64 of one run and the sizes they came from (the equations: module docstring)."""

    input_spikes: np.ndarray
    steps: np.ndarray
    synaptic_events: np.ndarray
    neuron_updates: np.ndarray
    template_macs: np.ndarray
    neurons: int
    inputs: int
    places: int

    def summary(self) -> CostSummary:
        """The means over queries (0 for no query)."""

        def mean(values: np.ndarray) -> float:
            return float(values.mean()) if values.size else 0.0

        return CostSummary(
            queries=int(self.steps.size),
            steps=mean(self.steps),
            input_spikes=mean(self.input_spikes),
            synaptic_events=mean(self.synaptic_events),
            neuron_updates=mean(self.neuron_updates),
            template_macs=mean(self.template_macs),
            snn_weights=self.inputs * self.neurons,  # the synapses the network holds: I J
            template_weights=self.places * self.inputs,  # the weights the template matcher holds: L I
        )


def joined_costs(costs: list[QueryCost]) -> QueryCost:
    """The costs of consecutive blocks of queries of one network as one: their per-query arrays concatenated."""

    def joined(name: str) -> np.ndarray:
        return np.concatenate([getattr(cost, name) for cost in costs])

    return replace(
        costs[0],
        input_spikes=joined("input_spikes"),
        steps=joined("steps"),
        synaptic_events=joined("synaptic_events"),
        neuron_updates=joined("neuron_updates"),
        template_macs=joined("template_macs"),
    )


def prefix_sums(per_step: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """sum_{t < T_q} a[q, t] for a (N, T) array and T_q per query: the cumulative sum read at T_q (0 for T_q = 0)."""
    cumulative = np.concatenate([np.zeros((per_step.shape[0], 1), np.int64), np.cumsum(per_step, axis=1)], axis=1)
    return cumulative[np.arange(per_step.shape[0]), steps]


def query_cost(
    spikes: object,
    neurons: int,
    *,
    places: int,
    images: np.ndarray | None = None,
    steps: np.ndarray | None = None,
    fan_out: np.ndarray | None = None,
) -> QueryCost:
    """The :class:`QueryCost` of presenting ``spikes`` (N, T, I) to ``neurons`` neurons (J = M n).

    ``steps``: T_q per query (None: all T). ``fan_out``: f_i per input (I,) (None: every input reaches all J
    neurons). ``images``: the query images x_q (N, I) the template matcher compares (None: the inputs that
    spiked at least once stand in for the non-zero ones, a lower bound on nnz(x_q)). ``places``: L.
    """
    arr = np.asarray(spikes)
    if arr.ndim != 3:
        raise InvalidValueError(f"spikes must be (N, T, inputs), got shape {arr.shape}")
    if arr.dtype != np.bool_ and not np.issubdtype(arr.dtype, np.integer):
        raise InvalidValueError(f"spikes must be 0/1 integers, got {arr.dtype}")
    n_queries, timesteps, n_inputs = arr.shape
    if neurons < 1 or places < 0:
        raise InvalidValueError(f"neurons must be >= 1 and places >= 0, got {neurons} and {places}")
    used = np.full(n_queries, timesteps, dtype=np.int64) if steps is None else np.asarray(steps)
    if used.shape != (n_queries,) or not np.issubdtype(used.dtype, np.integer):
        raise InvalidValueError(f"steps must be ({n_queries},) integers, got {used.dtype} of shape {used.shape}")
    if used.size and (used.min() < 0 or used.max() > timesteps):
        raise InvalidValueError(f"steps must lie in [0, {timesteps}], got {used.min()}..{used.max()}")
    used = used.astype(np.int64)
    per_step = arr.sum(axis=2, dtype=np.int64)
    if fan_out is None:
        events_per_step = per_step * neurons
    else:
        fan = np.asarray(fan_out)
        if fan.shape != (n_inputs,) or not np.issubdtype(fan.dtype, np.integer) or (fan.size and fan.min() < 0):
            raise InvalidValueError(f"fan_out must be ({n_inputs},) non-negative integers, got shape {fan.shape}")
        events_per_step = np.concatenate(
            [arr[a : a + CHUNK].astype(np.int64) @ fan.astype(np.int64) for a in range(0, n_queries, CHUNK)]
            or [np.zeros((0, timesteps), np.int64)]
        )
    if images is None:
        active = arr.any(axis=1)
    else:
        x = np.asarray(images)
        if x.shape != (n_queries, n_inputs):
            raise InvalidValueError(f"images must be ({n_queries}, {n_inputs}), got shape {x.shape}")
        active = x != 0
    return QueryCost(
        input_spikes=prefix_sums(per_step, used),
        steps=used,
        synaptic_events=prefix_sums(events_per_step, used),
        neuron_updates=used * neurons,
        template_macs=active.sum(axis=1, dtype=np.int64) * places,
        neurons=int(neurons),
        inputs=int(n_inputs),
        places=int(places),
    )


def nonzero_fan_out(weights: np.ndarray) -> np.ndarray:
    """f_i = #{j : w_ij != 0}, the synapses input i drives (weights (I, J)): what a chip that stores no zeros pays."""
    w = np.asarray(weights)
    if w.ndim != 2:
        raise InvalidValueError(f"weights must be (inputs, neurons), got shape {w.shape}")
    return np.count_nonzero(w, axis=1).astype(np.int64)
