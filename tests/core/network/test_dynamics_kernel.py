"""The compiled float kernel against run_network's torch loop (ties, ensembles, tiles, threads), and the BLAS-order sums."""

from __future__ import annotations

import pytest
import torch

from vprsnn_export.network import parallel
from vprsnn_export.network.dynamics import run_network
from vprsnn_export.network.dynamics_kernel import float_run

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def float_case(seed: int, n: int = 4, timesteps: int = 40, n_inputs: int = 30, n_neurons: int = 9):
    gen = torch.Generator().manual_seed(seed)
    weights = torch.rand((n_inputs, n_neurons), generator=gen)
    theta = 0.5 + 2 * torch.rand(n_neurons, generator=gen)
    spikes = (torch.rand((n, timesteps, n_inputs), generator=gen) < 0.2).to(torch.uint8)
    return spikes, weights, theta


@pytest.mark.parametrize("wta", [True, False])
@pytest.mark.parametrize("isolation", [True, False])
@pytest.mark.parametrize("group", [None, 3])
def test_float_kernel_matches_run_network(wta, isolation, group):
    """``group`` 3: an ensemble of three modules of three neurons, one WTA winner per module."""
    for seed in range(4):
        spikes, weights, theta = float_case(seed)
        slow = run_network(
            spikes,
            weights,
            theta,
            beta=0.95,
            wta=wta,
            state_isolation=isolation,
            record=True,
            compiled=False,
            group=group,
        )
        fast = float_run(spikes, weights, theta, beta=0.95, wta=wta, isolation=isolation, record=True, group=group)
        if wta and group:
            assert int(fast.raster.view(*fast.raster.shape[:2], 3, 3).sum(dim=3).max()) <= 1
            assert int(fast.raster.sum(dim=2).max()) > 1  # several modules fire in one step
        assert torch.equal(fast.raster, slow.raster)
        assert torch.equal(fast.counts, slow.counts)
        assert torch.equal(fast.candidates_per_step, slow.candidates_per_step)
        if isolation:
            assert torch.equal(fast.final_voltage, slow.final_voltage)


def test_float_kernel_exact_on_dyadic_weights_ties_to_the_lowest_index():
    """Weights that are multiples of 1/8 sum exactly in any order: the kernel must equal run_network bit for bit."""
    gen = torch.Generator().manual_seed(3)
    weights = torch.randint(0, 8, (25, 6), generator=gen).float() / 8
    weights[:, 3] = weights[:, 1]  # identical currents: ties
    theta = torch.tensor([1.0, 0.5, 2.0, 0.5, 1.5, 3.0])
    spikes = (torch.rand((3, 30, 25), generator=gen) < 0.3).to(torch.uint8)
    fast = float_run(spikes, weights, theta, beta=0.5, record=True)
    slow = run_network(spikes, weights, theta, beta=0.5, record=True, compiled=False)
    assert torch.equal(fast.raster, slow.raster) and torch.equal(fast.final_voltage, slow.final_voltage)


def test_an_ensemble_runs_each_module_as_it_would_run_alone():
    """Module m of an ensemble (grouped WTA) spikes exactly as the network of its neurons alone."""
    spikes, weights, theta = float_case(11, n_neurons=12)
    whole = float_run(spikes, weights, theta, beta=0.9, record=True, group=4)
    for module in range(3):
        cut = slice(4 * module, 4 * module + 4)
        alone = float_run(spikes, weights[:, cut].contiguous(), theta[cut].contiguous(), beta=0.9, record=True)
        assert torch.equal(whole.raster[:, :, cut], alone.raster)
    with pytest.raises(ValueError, match="do not divide"):
        float_run(spikes, weights, theta, beta=0.9, group=5)


@pytest.mark.parametrize("isolation", [True, False])
@pytest.mark.parametrize(("group", "threads"), [(None, 2), (4, 2), (4, 3), (1000, 2)])
def test_float_kernel_tiles_and_threads_change_no_number(isolation, group, threads, monkeypatch):
    """Tiles of whole WTA groups, threads over groups or presentations, a group wider than a tile summed in column
    blocks (the last one short) for chunks of presentations (the last one short): the same run as one thread, one
    tile."""
    n_neurons = {1000: 1000, None: 10}.get(group, 12)
    spikes, weights, theta = float_case(13, n=5, n_neurons=n_neurons)
    one = float_run(spikes, weights, theta, beta=0.9, isolation=isolation, record=True, group=group, threads=1)
    monkeypatch.setattr(parallel, "TILE_NEURONS", 4)
    monkeypatch.setattr(parallel, "CURRENT_BYTES", 2 * 4 * 40 * n_neurons)  # two presentations' currents
    assert parallel.current_blocks(40, 10, 1) == (10, 1)  # a lone presentation: one block
    assert parallel.current_blocks(40, parallel.neuron_tile(n_neurons, group or n_neurons), 5) == (
        (4, 2) if group in (None, 1000) else (4, 1)
    )
    many = float_run(spikes, weights, theta, beta=0.9, isolation=isolation, record=True, group=group, threads=threads)
    for field in ("counts", "candidates_per_step", "raster", "final_voltage"):
        assert torch.equal(getattr(one, field), getattr(many, field)), field


@pytest.mark.parametrize("group", [None, 40, 37])
def test_wide_wta_groups_pick_the_first_largest_candidate_as_run_network(group):
    """Groups wider than the 16 lanes of the branch-free argmax (and a ragged tail), with ties: run_network's winners."""
    for seed in range(3):
        spikes, weights, theta = float_case(seed, n=3, timesteps=60, n_neurons=(80 if group != 37 else 74))
        weights = torch.floor(weights * 4) / 8  # dyadic: exact sums, many tied currents
        theta = theta * 0.3
        slow = run_network(spikes, weights, theta, beta=0.95, record=True, compiled=False, group=group)
        fast = float_run(spikes, weights, theta, beta=0.95, record=True, group=group)
        assert int(slow.candidates_per_step.max()) > 16
        assert torch.equal(fast.raster, slow.raster) and torch.equal(fast.counts, slow.counts)


@pytest.mark.parametrize(("group", "threads"), [(None, 1), (4, 1), (4, 2)])
def test_a_lone_presentation_read_in_place_is_its_row_of_the_batch(group, threads, monkeypatch):
    """A lone presentation's currents read the weights in place (tiles from column 4, 8 on; threads over groups),
    a batch's from its copied tiles: every presentation alone gives its row of the batch, bit for bit."""
    monkeypatch.setattr(parallel, "TILE_NEURONS", 4)
    spikes, weights, theta = float_case(17, n=4, n_neurons=12)
    weights = weights * torch.logspace(-3, 2, 12)  # magnitudes apart: an order of the sums would show
    kw = dict(beta=0.9, record=True, group=group, threads=threads)
    batch = float_run(spikes, weights, theta, **kw)
    for p in range(len(spikes)):
        alone = float_run(spikes[p : p + 1], weights, theta, **kw)
        for field in ("counts", "raster", "final_voltage"):
            assert torch.equal(getattr(alone, field)[0], getattr(batch, field)[p]), field
