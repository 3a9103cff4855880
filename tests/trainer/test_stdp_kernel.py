"""The compiled STDP training window against train_batch's torch loop, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vprsnn_export.config import Config, preset
from vprsnn_export.network.kernel_sums import matches_torch
from vprsnn_export.trainer import train as train_module
from vprsnn_export.trainer.homeostasis import homeostasis_update
from vprsnn_export.trainer.stdp import initial_weights
from vprsnn_export.trainer.stdp_kernel import stdp_window
from vprsnn_export.trainer.train import Presentation, train_batch, train_network

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def tiny_training_config(wta: bool = True, weight_norm: bool = True) -> Config:
    return preset("paper").replace(
        **{
            "preprocess.image_size": 4,
            "preprocess.patch_size": 1,
            "network.n_inputs": 16,
            "network.n_neurons": 6,
            "network.theta_init": 0.8,
            "network.wta": wta,
            "stdp.weight_norm": weight_norm,
            "stdp.a_plus": 0.05,
            "stdp.a_minus": 0.01,
            "encoder.timesteps": 25,
            "encoder.rate_scale": 0.6,
            "train.epochs": 3,
            "train.batch_size": 4,
        }
    )


@pytest.mark.parametrize("wta,weight_norm", [(True, True), (False, True), (True, False)])
def test_stdp_window_gives_train_batch_weights_bit_for_bit(wta, weight_norm):
    cfg = tiny_training_config(wta, weight_norm)
    gen = torch.Generator().manual_seed(5)
    weights = initial_weights(16, 6, gen)
    theta = torch.full((6,), 0.8)
    spikes = (torch.rand((4, 25, 16), generator=gen) < 0.4).to(torch.uint8)
    if not matches_torch(4, 16, 6):
        pytest.skip("this machine's BLAS order is not reproducible")
    compiled = stdp_window(weights, theta, spikes, cfg)
    assert compiled is not None
    expected_weights, _, expected_fired = train_batch(weights, theta, spikes, cfg, compiled=False)
    assert torch.equal(compiled[0], expected_weights)
    assert torch.equal(compiled[1], expected_fired)


def test_training_through_the_kernel_gives_identical_weights(monkeypatch):
    """train_network with its batch loop routed through stdp_window: the same weights and thresholds for the seed."""
    cfg = tiny_training_config()
    rng = np.random.default_rng(0)
    images = rng.random((10, 16)).astype(np.float32)
    presentations = [Presentation("summer", p) for p in range(10)]

    def torch_batch(weights, theta, spikes, cfg):
        return train_batch(weights, theta, spikes, cfg, compiled=False)

    monkeypatch.setattr(train_module, "train_batch", torch_batch)
    expected = train_network(images, presentations, cfg, device=torch.device("cpu"), progress=False)

    def compiled_batch(weights, theta, spikes, cfg):
        if not matches_torch(spikes.shape[0], spikes.shape[2], weights.shape[1]):
            pytest.skip("this machine's BLAS order is not reproducible")
        result = stdp_window(weights, theta, spikes, cfg)
        assert result is not None
        weights, fired = result
        batch, timesteps, _ = spikes.shape
        return weights, homeostasis_update(theta, fired / (batch * timesteps), cfg.homeostasis), fired

    monkeypatch.setattr(train_module, "train_batch", compiled_batch)
    got = train_network(images, presentations, cfg, device=torch.device("cpu"), progress=False)
    assert torch.equal(got.weights, expected.weights)
    assert torch.equal(got.thresholds, expected.thresholds)


def test_the_kernel_trains_in_its_own_order_where_blas_is_not_reproducible(monkeypatch):
    """No probed block (MKL's small-batch sgemm): the kernel still runs, sums left to right, and stays near torch."""
    from vprsnn_export.network import kernel_sums

    monkeypatch.setattr(kernel_sums, "blas_block", lambda *shape: None)
    cfg = tiny_training_config()
    gen = torch.Generator().manual_seed(8)
    weights = initial_weights(16, 6, gen)
    theta = torch.full((6,), 0.8)
    spikes = (torch.rand((4, 25, 16), generator=gen) < 0.4).to(torch.uint8)
    assert kernel_sums.kernel_block(4, 16, 6) == 16 and not kernel_sums.matches_torch(4, 16, 6)
    first, second = stdp_window(weights, theta, spikes, cfg), stdp_window(weights, theta, spikes, cfg)
    assert first is not None and second is not None
    assert torch.equal(first[0], second[0]) and torch.equal(first[1], second[1])
    expected_weights, _, expected_fired = train_batch(weights, theta, spikes, cfg, compiled=False)
    assert torch.allclose(first[0], expected_weights, atol=1e-5)
