"""The compiled STDP training window against train_batch's torch loop: bit for bit where no sum's order can
matter, to float32 rounding elsewhere."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vprsnn_export.config import Config, preset
from vprsnn_export.trainer import stdp_kernel
from vprsnn_export.trainer import train as train_module
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
def test_stdp_window_gives_train_batch_weights_bit_for_bit_where_no_sum_can_differ(wta, weight_norm):
    """Weights on a 1/8 grid (every current exact, in any order), one step and a batch of two (a sum of two
    terms is the same either way round): the kernel is then the torch loop bit for bit, so every other float32
    operation (WTA, traces, STDP, clip, normalisation) runs in torch's order."""
    cfg = tiny_training_config(wta, weight_norm)
    gen = torch.Generator().manual_seed(5)
    weights = torch.randint(0, 9, (16, 6), generator=gen).float() / 8
    theta = torch.full((6,), 0.8)
    spikes = (torch.rand((2, 1, 16), generator=gen) < 0.4).to(torch.uint8)
    compiled = stdp_window(weights, theta, spikes, cfg)
    assert compiled is not None
    expected_weights, _, expected_fired = train_batch(weights, theta, spikes, cfg, compiled=False)
    assert int(expected_fired.sum()) > 0 and not torch.equal(expected_weights, weights)  # STDP acted
    assert torch.equal(compiled[0], expected_weights)
    assert torch.equal(compiled[1], expected_fired)


@pytest.mark.parametrize("wta,weight_norm", [(True, True), (False, True), (True, False)])
def test_the_kernel_trains_in_its_own_order_the_same_every_time_and_near_torch(wta, weight_norm):
    """A whole window: the kernel sums the currents in increasing input order (the torch loop in its BLAS's):
    the same weights on every call, and the torch loop's to float32 rounding."""
    cfg = tiny_training_config(wta, weight_norm)
    gen = torch.Generator().manual_seed(8)
    weights = initial_weights(16, 6, gen)
    theta = torch.full((6,), 0.8)
    spikes = (torch.rand((4, 25, 16), generator=gen) < 0.4).to(torch.uint8)
    first, second = stdp_window(weights, theta, spikes, cfg), stdp_window(weights, theta, spikes, cfg)
    assert first is not None and second is not None
    assert torch.equal(first[0], second[0]) and torch.equal(first[1], second[1])
    expected_weights, _, _ = train_batch(weights, theta, spikes, cfg, compiled=False)
    assert torch.allclose(first[0], expected_weights, atol=1e-5)


def test_training_through_the_kernel_is_the_torch_loops_to_float32_rounding(monkeypatch):
    """train_network with its batch loop routed through the torch loop and through stdp_window (as on the CPU):
    weights and thresholds within float32 rounding of each other, and the kernel's the same on a second run."""
    cfg = tiny_training_config()
    rng = np.random.default_rng(0)
    images = rng.random((10, 16)).astype(np.float32)
    presentations = [Presentation("summer", p) for p in range(10)]

    def torch_batch(weights, theta, spikes, cfg, compiled=True):
        return train_batch(weights, theta, spikes, cfg, compiled=False)

    monkeypatch.setattr(train_module, "train_batch", torch_batch)
    expected = train_network(images, presentations, cfg, device=torch.device("cpu"), progress=False)
    monkeypatch.undo()
    got = train_network(images, presentations, cfg, device=torch.device("cpu"), progress=False)
    again = train_network(images, presentations, cfg, device=torch.device("cpu"), progress=False)
    assert torch.equal(got.weights, again.weights) and torch.equal(got.thresholds, again.thresholds)
    assert torch.allclose(got.weights, expected.weights, atol=1e-4)
    assert torch.allclose(got.thresholds, expected.thresholds, atol=1e-4)


def _module_batch(n_modules: int):
    """Random limits, seeds and starting weights of ``n_modules`` small modules (3 rows each, 6 inputs, 4 neurons)."""
    rng = np.random.default_rng(n_modules)
    limits = (rng.random((n_modules, 3, 6)) * (1 << 23)).astype(np.int32)
    seeds = rng.integers(0, 2**31, (n_modules, 3), dtype=np.int64)
    weights = rng.random((n_modules, 6, 4)).astype(np.float32)
    theta = np.full((n_modules, 4), 0.5, dtype=np.float32)
    return limits, seeds, np.full(n_modules, 3, dtype=np.int64), weights, theta


@pytest.mark.parametrize("threads", [1, 2])
def test_a_batch_runs_in_slices_of_modules_with_the_weights_of_one_call(threads, monkeypatch):
    cfg = preset("paper").replace(**{"train.timesteps": 5})
    limits, seeds, sizes, weights, theta = _module_batch(7)
    whole = weights.copy()
    monkeypatch.setattr(stdp_kernel, "MODULES_PER_CALL", 7)
    fired_whole = stdp_kernel.stdp_windows(whole, theta, limits, seeds, sizes, cfg, threads=1)
    calls: list[int] = []
    real = stdp_kernel.stdp_windows_kernel
    monkeypatch.setattr(stdp_kernel, "MODULES_PER_CALL", 2)
    monkeypatch.setattr(
        stdp_kernel, "stdp_windows_kernel", lambda limits, *a: calls.append(len(limits)) or real(limits, *a)
    )
    fired = stdp_kernel.stdp_windows(weights, theta, limits, seeds, sizes, cfg, threads=threads)
    assert sorted(calls) == [1, 2, 2, 2]  # 7 modules in 4 slices
    assert np.array_equal(fired, fired_whole) and np.array_equal(weights, whole)


def test_an_interrupt_during_a_batch_waits_for_the_slices_in_flight_only(monkeypatch):
    cfg = preset("paper").replace(**{"train.timesteps": 5})
    limits, seeds, sizes, weights, theta = _module_batch(40)
    started: list[int] = []

    def interrupted(limits, *args):
        started.append(len(limits))
        if len(started) == 2:
            raise KeyboardInterrupt
        return np.zeros((len(limits), 4), dtype=np.float32)

    monkeypatch.setattr(stdp_kernel, "MODULES_PER_CALL", 1)
    monkeypatch.setattr(stdp_kernel, "stdp_windows_kernel", interrupted)
    with pytest.raises(KeyboardInterrupt):
        stdp_kernel.stdp_windows(weights, theta, limits, seeds, sizes, cfg, threads=2)
    assert max(started) == 1 and len(started) < 10  # 40 slices of one module: the queued ones were cancelled
