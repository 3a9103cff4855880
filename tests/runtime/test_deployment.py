"""QuantiseOptions, validated once when built; deploying without the leak (quantize --non-leaky): decay_dv = 0,
an IF node, exact in every float consumer."""

from __future__ import annotations

import json

import nir
import numpy as np
import pytest

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.quantize import QuantiseOptions
from vprsnn_export.runtime.deployment import deploy
from vprsnn_export.targets.nir_target import write_nir


def test_non_leaky_deployment_has_no_decay_and_says_so(tmp_path, make_checkpoint):
    ckpt = make_checkpoint(np.random.default_rng(5), uniform=True)
    images = {"summer": np.random.default_rng(6).random((3, 16)).astype(np.float32)}
    leaky = deploy(ckpt, "0" * 64, 8, reference_images=images)
    model = deploy(ckpt, "0" * 64, 8, QuantiseOptions(non_leaky=True), reference_images=images)
    assert leaky.decay_dv == 205 and model.decay_dv == 0 and model.config.network.beta == 1.0
    assert np.array_equal(model.weight_mantissa, leaky.weight_mantissa)  # the trained weights, unchanged
    graph = nir.read(write_nir(model, tmp_path / "m.nir"))
    assert isinstance(graph.nodes["lif"], nir.IF)
    assert np.allclose(graph.nodes["lif"].r, 1 / graph.metadata["dt"])
    statement = json.loads(graph.metadata["float_consumers"])
    assert statement == {**statement, "mode": "non-leaky (IF)", "exact": True, "decision_tolerance": 1.0}
    assert json.loads(graph.metadata["integer_semantics"])["decay"]["multiplier"] == 4096


@pytest.mark.parametrize(
    ("given", "message"),
    [
        ({"calibration": "float", "non_leaky": True}, r"non_leaky \(--non-leaky\) needs the deployed calibration"),
        ({"per_neuron": False, "fold_thresholds": True}, r"fold_thresholds \(--fold-thresholds\) needs per-neuron"),
        ({"scale_method": "p99"}, r"scale_method \(--scale\) must be one of max, mse, got 'p99'"),
        ({"calibration": "integer"}, "calibration must be one of deployed, float, got 'integer'"),
        ({"non_leaky": "yes"}, "non_leaky must be True or False"),
        ({"per_neuron": 1}, "per_neuron must be True or False"),
    ],
)
def test_quantise_options_are_checked_once_when_built(given, message):
    with pytest.raises(InvalidValueError, match=message):
        QuantiseOptions(**given)


def test_deploy_takes_the_options_object_and_nothing_else(make_checkpoint):
    ckpt = make_checkpoint(np.random.default_rng(5), uniform=True)
    with pytest.raises(InvalidValueError, match="ckpt must be a Checkpoint, got str"):
        deploy("net.npz", "0" * 64, 8)  # type: ignore[arg-type]  # named first, not as missing reference images
    with pytest.raises(InvalidValueError, match="options must be a QuantiseOptions, got dict"):
        deploy(ckpt, "0" * 64, 8, {"calibration": "float"})  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="non_leaky"):
        deploy(ckpt, "0" * 64, 8, non_leaky=True)  # type: ignore[call-arg]
    with pytest.raises(InvalidValueError, match="needs the reference images"):
        deploy(ckpt, "0" * 64, 8, QuantiseOptions(non_leaky=True))
    folded = deploy(ckpt, "0" * 64, 8, QuantiseOptions(fold_thresholds=True, calibration="float"))
    assert folded.quantisation.threshold_folding and len(set(folded.threshold.tolist())) == 1
