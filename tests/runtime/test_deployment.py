"""Deploying without the leak (quantize --non-leaky): decay_dv = 0, an IF node, exact in every float consumer."""

from __future__ import annotations

import json

import nir
import numpy as np
import pytest

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.runtime.deployment import deploy
from vprsnn_export.targets.nir_target import write_nir


def test_non_leaky_deployment_has_no_decay_and_says_so(tmp_path, make_checkpoint):
    ckpt = make_checkpoint(np.random.default_rng(5), uniform=True)
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


def test_non_leaky_deployment_needs_the_deployed_calibration(make_checkpoint):
    with pytest.raises(InvalidValueError, match="deployed calibration"):
        deploy(
            make_checkpoint(np.random.default_rng(5), uniform=True), "0" * 64, 8, calibration="float", non_leaky=True
        )
