"""Shared test factories: a small config, a random fixed-point model, one torch thread.

The tests import in importlib mode, so the factories are handed out as fixtures:
``def test_x(make_model): model = make_model(rng, bits=4)``. A module that wants one
intra-op thread for its tiny tensors says ``pytestmark = pytest.mark.usefixtures("one_thread")``.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import settings

from vprsnn_export.config import Config, preset
from vprsnn_export.export.model import FixedPointModel

#: Property tests are judged on their examples, never on time: the 2-core machine is shared, and a
#: per-example deadline fails a correct test under load. One profile for every test module.
settings.register_profile("vprsnn", deadline=None)
settings.load_profile("vprsnn")


@pytest.fixture
def one_thread():
    """Small tensors: one intra-op thread avoids oversubscribing the shared cores."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _small_config(n_inputs: int = 16, n_neurons: int = 6, **overrides) -> Config:
    """The paper's preset on sqrt(n_inputs) x sqrt(n_inputs) images, one pixel per patch, 20 time steps."""
    side = int(round(n_inputs**0.5))
    return preset("paper").replace(
        **{
            "preprocess.image_size": side,
            "preprocess.patch_size": 1,
            "network.n_inputs": n_inputs,
            "network.n_neurons": n_neurons,
            "encoder.timesteps": 20,
            **overrides,
        }
    )


def _make_model(
    rng: np.random.Generator,
    *,
    bits: int = 8,
    wta: bool = True,
    dv: int = 205,
    uniform: bool = False,
    n_inputs: int = 16,
    n_neurons: int = 6,
) -> FixedPointModel:
    """A random fixed-point model of n_neurons over n_inputs with three reference places (5, 7, 9)."""
    cfg = _small_config(n_inputs, n_neurons, **{"network.wta": wta})
    threshold = np.full(n_neurons, 300) if uniform else rng.integers(50, 600, n_neurons)
    return FixedPointModel(
        bits=bits,
        weight_mantissa=rng.integers(0, 2**bits, (n_inputs, n_neurons)).astype(np.int32),
        scale_multiplier=rng.integers(1, 2**16, n_neurons).astype(np.int32),
        scale_exponent=-20,
        threshold=threshold.astype(np.int32),
        decay_dv=dv,
        config=cfg,
        calibration=rng.integers(0, 4, (n_neurons, 3)).astype(np.int64),
        float_calibration=rng.integers(0, 4, (n_neurons, 3)).astype(np.int64),
        reference_place_ids=np.array([5, 7, 9], dtype=np.int64),
        reference_traversals=["summer"],
        quantisation={"per_neuron": True, "scale_method": "max"},
        source_sha256="ab" * 32,
        data={"source": "synthetic"},
    )


@pytest.fixture
def tiny_model() -> FixedPointModel:
    """A 4-input, 3-neuron 4-bit fixed-point model with hand-set integers (thresholds 4, mantissas 3)."""
    cfg = preset("paper").replace(
        **{"preprocess.image_size": 2, "preprocess.patch_size": 1, "network.n_inputs": 4, "network.n_neurons": 3}
    )
    return FixedPointModel(
        bits=4,
        weight_mantissa=np.full((4, 3), 3, dtype=np.int32),
        scale_multiplier=np.ones(3, dtype=np.int32),
        scale_exponent=-8,
        threshold=np.full(3, 4, dtype=np.int32),
        decay_dv=400,
        config=cfg,
        calibration=np.zeros((3, 1), dtype=np.int64),
        float_calibration=np.zeros((3, 1), dtype=np.int64),
        reference_place_ids=np.zeros(1, dtype=np.int64),
        reference_traversals=["summer"],
        quantisation={"per_neuron": True},
        source_sha256="0" * 64,
    )


@pytest.fixture
def small_config():
    """The factory ``small_config(n_inputs=16, n_neurons=6, **overrides) -> Config``."""
    return _small_config


@pytest.fixture
def make_model():
    """The factory ``make_model(rng, *, bits, wta, dv, uniform, n_inputs, n_neurons) -> FixedPointModel``."""
    return _make_model
