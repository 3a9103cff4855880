"""The energy and latency estimate per query (targets/loihi_budget.py: query_estimate, deployment_cost)."""

import numpy as np
import pytest

from vprsnn_export.network.cost import CostSummary
from vprsnn_export.targets.loihi_budget import LOIHI1, LOIHI1_OPERATIONS, core_budget, deployment_cost, query_estimate


def test_estimate_by_hand():
    cost = CostSummary(
        queries=1,
        steps=10.0,
        input_spikes=5.0,
        synaptic_events=500.0,
        neuron_updates=1000.0,
        template_macs=0.0,
        snn_weights=1600,
        template_weights=16,
    )
    budget = core_budget(1, 100, 16, 8, LOIHI1)
    assert budget.neurons_per_core == 100
    estimate = query_estimate(cost, budget)
    # 500 x 23.6 pJ + 1000 x 81 pJ = 92,800 pJ
    assert estimate.energy_uj == pytest.approx(0.0928)
    # 5 spikes x 100 neurons x 3.5 ns + 10 steps x (100 x 8.4 ns + 465 ns) = 1,750 + 13,050 ns
    assert estimate.latency_ms == pytest.approx(0.0148)
    assert estimate.chip == "Loihi 1" and "Davies" in estimate.source and "pre-silicon" in LOIHI1_OPERATIONS.source


def test_deployment_cost_without_and_with_spikes(make_model):
    model = make_model(np.random.default_rng(0), n_inputs=16, n_neurons=6)
    structural = deployment_cost(model)
    assert structural == {"steps": 20, "neuron_updates": 120, "synaptic_events_per_input_spike": 6}
    spikes = np.zeros((2, 20, 16), dtype=np.uint8)
    spikes[0, :, 0] = 1  # 20 input spikes
    spikes[1, :10, :2] = 1  # 20 input spikes
    measured = deployment_cost(model, spikes, "two queries")
    assert measured["measured_on"] == "two queries"
    assert measured["per_query"]["synaptic_events"] == 120.0 and measured["per_query"]["input_spikes"] == 20.0
    (estimate,) = measured["estimates"]
    assert estimate["energy_uj"] == pytest.approx((120 * 23.6 + 120 * 81.0) * 1e-6)
