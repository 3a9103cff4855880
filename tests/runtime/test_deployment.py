"""Deploying without the leak (quantize --non-leaky): decay_dv = 0, an IF node, exact in every float consumer."""

from __future__ import annotations

import json

import nir
import numpy as np
import pytest

from vprsnn_export.config import preset
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.runtime.deployment import deploy
from vprsnn_export.targets.nir_target import write_nir


def tiny_checkpoint() -> Checkpoint:
    rng = np.random.default_rng(5)
    cfg = preset("paper").replace(
        **{
            "preprocess.image_size": 4,
            "preprocess.patch_size": 1,
            "network.n_inputs": 16,
            "network.n_neurons": 6,
            "encoder.timesteps": 20,
        }
    )
    return Checkpoint(
        config=cfg,
        weights=(rng.random((16, 6)) * 0.5).astype(np.float32),
        thresholds=np.full(6, 2.25, dtype=np.float32),
        calibration=rng.integers(0, 4, (6, 3)).astype(np.int64),
        reference_place_ids=np.array([1, 2, 3], dtype=np.int64),
        reference_traversals=["summer"],
        data={"source": "synthetic", "subset": None},
        history=[],
    )


def test_non_leaky_deployment_has_no_decay_and_says_so(tmp_path):
    ckpt = tiny_checkpoint()
    images = {"summer": np.random.default_rng(6).random((3, 16)).astype(np.float32)}
    leaky = deploy(ckpt, "0" * 64, 8, reference_images=images)
    model = deploy(ckpt, "0" * 64, 8, reference_images=images, non_leaky=True)
    assert leaky.decay_dv == 205 and model.decay_dv == 0 and model.config.network.beta == 1.0
    assert np.array_equal(model.weight_mantissa, leaky.weight_mantissa)  # the trained weights, unchanged
    graph = nir.read(write_nir(model, tmp_path / "m.nir"))
    assert isinstance(graph.nodes["lif"], nir.IF)
    assert np.allclose(graph.nodes["lif"].r, 1 / graph.metadata["dt"])
    statement = json.loads(graph.metadata["float_consumers"])
    assert statement == {**statement, "mode": "non-leaky (IF)", "exact": True, "decision_tolerance": 1.0}
    assert json.loads(graph.metadata["integer_semantics"])["decay"]["multiplier"] == 4096


def test_non_leaky_deployment_needs_the_deployed_calibration():
    with pytest.raises(InvalidValueError, match="deployed calibration"):
        deploy(tiny_checkpoint(), "0" * 64, 8, calibration="float", non_leaky=True)
