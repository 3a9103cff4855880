"""The torch integer path on any device equals the compiled CPU kernel bit for bit on the same spikes.

The torch path (:func:`vprsnn_export.targets.intsim.run_prepared` with ``compiled=False``, and
every non-CPU device) runs all queries of a chunk and all modules at once, one step at a time.
The CPU case runs here; the CUDA case runs where torch sees a GPU and is skipped otherwise.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vprsnn_export.config import preset
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.targets.intsim import prepare, run_prepared

DEVICES = [
    "cpu",
    pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="torch sees no CUDA GPU")),
]


pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def ensemble_model(modules: int, n: int, *, per_neuron: bool, wta: bool = True, seed: int = 0) -> FixedPointModel:
    """A random 8-bit ensemble of ``modules`` modules of ``n`` neurons on 784 inputs, thresholds that fire often."""
    gen = np.random.default_rng(seed)
    n_neurons = modules * n
    cfg = preset("paper").replace(
        **{"network.n_neurons": n, "train.module_size": 1, "encoder.timesteps": 40, "network.wta": wta}
    )
    return FixedPointModel(
        bits=8,
        weight_mantissa=gen.integers(0, 256, (784, n_neurons)).astype(np.int32),
        scale_multiplier=(gen.integers(1, 2**16, n_neurons) if per_neuron else np.full(n_neurons, 777)).astype(
            np.int32
        ),
        scale_exponent=-20,
        threshold=gen.integers(20_000, 60_000, n_neurons).astype(np.int32),
        decay_dv=409,
        config=cfg,
        calibration=np.zeros((n_neurons, modules), dtype=np.int64),
        float_calibration=np.zeros((n_neurons, modules), dtype=np.int64),
        reference_place_ids=np.arange(modules, dtype=np.int64),
        reference_traversals=["summer"],
        quantisation={"per_neuron": per_neuron},
        source_sha256="0" * 64,
    )


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize(
    ("per_neuron", "wta", "isolation"),
    [(True, True, True), (False, True, True), (True, False, True), (True, True, False)],
)
def test_torch_integer_path_equals_the_cpu_kernel(device, per_neuron, wta, isolation):
    model = ensemble_model(6, 16, per_neuron=per_neuron, wta=wta)
    n_queries = 130 if isolation else 4  # with isolation: more than one chunk of 128 queries
    images = np.random.default_rng(1).random((n_queries, 784)).astype(np.float32)
    spikes = query_spikes(images, np.arange(n_queries), "winter", model.config)
    kernel = run_prepared(prepare(model, torch.device("cpu")), spikes, isolation=isolation, record=True)
    loop = run_prepared(prepare(model, torch.device(device)), spikes, isolation=isolation, record=True, compiled=False)
    assert kernel.counts.sum() > 0 and int(kernel.candidates_per_step.max()) > 1  # WTA has real work
    assert torch.equal(loop.counts, kernel.counts)
    assert torch.equal(loop.raster, kernel.raster)
    assert torch.equal(loop.candidates_per_step, kernel.candidates_per_step)
    assert torch.equal(loop.final_voltage, kernel.final_voltage)
    assert loop.saturations == kernel.saturations
