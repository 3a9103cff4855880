import torch

from vprsnn_export.network.dynamics import run_network, wta_step


def test_wta_step_picks_largest_current_among_candidates_and_resets_all_candidates():
    voltage = torch.tensor([[1.0, 0.0, 2.0, 0.0]])
    current = torch.tensor([[0.5, 3.0, 0.5, 0.1]])
    theta = torch.tensor([1.0, 1.0, 1.0, 5.0])
    new_v, spikes, candidates = wta_step(voltage, current, theta, beta=0.5, wta=True)
    # V = 0.5 V + I = [1.0, 3.0, 1.5, 0.1]; candidates V > theta: neurons 1 and 2
    assert candidates.tolist() == [[False, True, True, False]]
    assert spikes.tolist() == [[False, True, False, False]]  # largest current among candidates
    assert torch.allclose(new_v, torch.tensor([[1.0, 0.0, 0.0, 0.1]]))


def test_wta_winner_is_restricted_to_candidates():
    # neuron 0 has the largest current but stays below threshold: it must not win
    voltage = torch.zeros(1, 2)
    current = torch.tensor([[5.0, 2.0]])
    theta = torch.tensor([10.0, 1.0])
    _, spikes, _ = wta_step(voltage, current, theta, beta=1.0, wta=True)
    assert spikes.tolist() == [[False, True]]


def test_wta_ties_go_to_lowest_index():
    current = torch.tensor([[2.0, 3.0, 3.0, 3.0]])
    theta = torch.tensor([1.0, 5.0, 1.0, 1.0])
    _, spikes, _ = wta_step(torch.zeros(1, 4), current, theta, beta=0.9, wta=True)
    assert spikes.tolist() == [[False, False, True, False]]


def test_no_candidate_means_no_spike_and_wta_off_fires_every_candidate():
    current = torch.tensor([[0.5, 0.2], [2.0, 3.0]])
    theta = torch.tensor([1.0, 1.0])
    _, spikes, _ = wta_step(torch.zeros(2, 2), current, theta, beta=0.9, wta=True)
    assert spikes.tolist() == [[False, False], [False, True]]
    _, spikes_off, _ = wta_step(torch.zeros(2, 2), current, theta, beta=0.9, wta=False)
    assert spikes_off.tolist() == [[False, False], [True, True]]


def test_state_isolation_off_carries_voltage_between_presentations():
    weights = torch.tensor([[0.6]])
    theta = torch.tensor([1.0])
    spikes = torch.ones((2, 1, 1), dtype=torch.uint8)  # two presentations of one step each
    isolated = run_network(spikes, weights, theta, beta=1.0, state_isolation=True)
    carried = run_network(spikes, weights, theta, beta=1.0, state_isolation=False)
    assert isolated.counts.flatten().tolist() == [0, 0]
    assert carried.counts.flatten().tolist() == [0, 1]  # 0.6 + 0.6 > 1 only when V carries over


def test_run_network_is_independent_of_batching():
    gen = torch.Generator().manual_seed(0)
    weights = torch.rand((20, 8), generator=gen)
    theta = torch.full((8,), 1.5)
    spikes = (torch.rand((5, 30, 20), generator=gen) < 0.3).to(torch.uint8)
    whole = run_network(spikes, weights, theta, beta=0.95, record=True)
    parts = [run_network(spikes[i : i + 1], weights, theta, beta=0.95, record=True) for i in range(5)]
    assert torch.equal(whole.raster, torch.cat([p.raster for p in parts]))
    assert torch.equal(whole.counts, whole.raster.sum(dim=1))
