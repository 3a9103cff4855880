"""Scale choices, per-tensor/per-neuron scaling, threshold folding, recalibration and the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from vprsnn_export.cli import main
from vprsnn_export.config import preset
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import load_fixed_point
from vprsnn_export.export.quantize import (
    QuantiseOptions,
    column_sse,
    desired_scales,
    quantise_arrays,
    quantize_checkpoint,
    split_scales,
)
from vprsnn_export.io.checkpoint import Checkpoint, save_checkpoint
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.runtime.deployment import recalibrate
from vprsnn_export.trainer.calibrate import calibrate
from vprsnn_export.trainer.stdp import initial_weights

SMALL = {"network.n_neurons": 12, "encoder.timesteps": 24}


pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def stdp_like_weights(n_inputs: int = 784, n_neurons: int = 12, seed: int = 0) -> np.ndarray:
    """Non-negative, column-normalised, skewed (a few large weights per column), like trained STDP weights."""
    rng = np.random.default_rng(seed)
    w = rng.random((n_inputs, n_neurons)) ** 4
    return (w / np.linalg.norm(w, axis=0)).astype(np.float32)


def thresholds(n_neurons: int = 12, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed + 1).uniform(0.6, 2.5, n_neurons).astype(np.float32)


@pytest.mark.parametrize("bits", [2, 3, 4, 8])
def test_max_per_neuron_uses_the_full_unsigned_range_without_clipping(bits):
    w = stdp_like_weights()
    q = quantise_arrays(
        w, thresholds(), bits, QuantiseOptions(per_neuron=True, scale_method="max", fold_thresholds=False)
    )
    assert q.weight_mantissa.min() == 0 and q.weight_mantissa.max(axis=0).tolist() == [2**bits - 1] * 12
    assert q.report["weights_clipped"] == 0
    scales = q.scale_multiplier * 2.0**q.scale_exponent
    assert np.all(np.abs(w - q.weight_mantissa * scales) <= scales / 2 + 1e-12)


def test_two_bits_are_four_unsigned_levels():
    q = quantise_arrays(
        stdp_like_weights(),
        thresholds(),
        2,
        QuantiseOptions(per_neuron=True, scale_method="max", fold_thresholds=False),
    )
    assert set(np.unique(q.weight_mantissa).tolist()) == {0, 1, 2, 3}


def test_per_tensor_shares_one_scale_and_maps_the_largest_weight_to_the_top_level():
    w = stdp_like_weights()
    q = quantise_arrays(
        w, thresholds(), 4, QuantiseOptions(per_neuron=False, scale_method="max", fold_thresholds=False)
    )
    assert np.unique(q.scale_multiplier).size == 1
    assert q.weight_mantissa.max() == 15 and q.weight_mantissa[np.unravel_index(w.argmax(), w.shape)] == 15


def test_per_neuron_error_is_not_worse_than_per_tensor_and_errors_shrink_with_bits():
    w, th = stdp_like_weights(), thresholds()
    rmse = {}
    for per_neuron in (False, True):
        for bits in (2, 4, 8):
            rmse[per_neuron, bits] = quantise_arrays(
                w, th, bits, QuantiseOptions(per_neuron=per_neuron, scale_method="max", fold_thresholds=False)
            ).report["weight_rmse"]
        assert rmse[per_neuron, 8] < rmse[per_neuron, 4] < rmse[per_neuron, 2]
    assert all(rmse[True, b] <= rmse[False, b] for b in (2, 4, 8))


@pytest.mark.parametrize("per_neuron", [False, True])
@pytest.mark.parametrize("bits", [2, 3, 8])
def test_mse_scales_never_have_more_squared_error_than_max(bits, per_neuron):
    w = stdp_like_weights().astype(np.float64)
    mse = column_sse(w, desired_scales(w, bits, "mse", per_neuron), bits)
    top = column_sse(w, desired_scales(w, bits, "max", per_neuron), bits)
    if per_neuron:
        assert np.all(mse <= top + 1e-15)
    assert mse.sum() <= top.sum() + 1e-15  # per tensor the search minimises the total
    if bits == 2:
        assert mse.sum() < top.sum()  # skewed weights: clipping a few large ones pays at low precision


def test_split_scales_keeps_sixteen_significant_bits():
    scales = np.array([3.1e-3, 7.7e-4, 1.2e-2, 5.0e-3])
    m, e = split_scales(scales)
    assert 2**15 <= m.max() < 2**16 and m.min() >= 1
    assert np.all(np.abs(m * 2.0**e - scales) / scales <= 2.0**-15 * (scales.max() / scales))


@pytest.mark.parametrize("method", ["max", "mse"])
@pytest.mark.parametrize("bits", [2, 4, 8])
def test_threshold_folding_gives_one_integer_threshold_and_keeps_float_thresholds(bits, method):
    w, th = stdp_like_weights(), thresholds()
    q = quantise_arrays(w, th, bits, QuantiseOptions(per_neuron=True, scale_method=method, fold_thresholds=True))
    assert np.unique(q.threshold).size == 1 and q.threshold[0] == q.report["shared_threshold"]
    assert q.report["threshold_max_relative_error"] < 2.0**-13
    if method == "max":
        assert q.report["weights_clipped"] == 0


def test_folding_needs_per_neuron_scales_and_methods_are_checked():
    with pytest.raises(InvalidValueError, match="per-neuron"):
        quantise_arrays(
            stdp_like_weights(),
            thresholds(),
            4,
            QuantiseOptions(per_neuron=False, scale_method="max", fold_thresholds=True),
        )
    with pytest.raises(InvalidValueError, match="scale_method"):
        quantise_arrays(
            stdp_like_weights(),
            thresholds(),
            4,
            QuantiseOptions(per_neuron=True, scale_method="p99", fold_thresholds=False),
        )
    with pytest.raises(InvalidValueError, match="unsupported weight bit width"):
        quantise_arrays(
            stdp_like_weights(),
            thresholds(),
            1,
            QuantiseOptions(per_neuron=True, scale_method="max", fold_thresholds=False),
        )


def test_a_dead_neuron_gets_a_representable_threshold():
    w = stdp_like_weights()
    w[:, 3] = 0.0
    q = quantise_arrays(w, thresholds(), 4, QuantiseOptions(per_neuron=True, scale_method="mse", fold_thresholds=False))
    assert np.all(q.weight_mantissa[:, 3] == 0) and 1 <= q.threshold[3] < 2**17
    assert q.report["thresholds_clipped"] == 0


def small_checkpoint(n_places: int = 6) -> tuple[Checkpoint, dict]:
    """A float network (initial STDP weights) calibrated on the synthetic route."""
    cfg = preset("paper").replace(**SMALL)
    data = load_dataset(f"synthetic:{n_places}", ["summer", "winter"], cfg.preprocess)
    weights = initial_weights(784, 12, torch.Generator().manual_seed(0)).numpy()
    theta = thresholds()
    network = FloatNetwork.from_arrays(weights, theta, cfg, torch.device("cpu"))
    reference = {"summer": data.traversal("summer")}
    ckpt = Checkpoint(
        config=cfg,
        weights=weights,
        thresholds=theta,
        calibration=calibrate(network.counts, reference, data.place_ids, cfg),
        reference_place_ids=data.place_ids,
        reference_traversals=["summer"],
        data={
            "source": f"synthetic:{n_places}",
            "manifest_sha256": data.manifest_sha256,
            "subset": None,
            "places": None,
        },
    )
    return ckpt, reference


def test_quantize_checkpoint_then_recalibrate_on_the_integer_simulator():
    ckpt, reference = small_checkpoint()
    model = quantize_checkpoint(ckpt, "cd" * 32, 8, QuantiseOptions())
    assert model.source_sha256 == "cd" * 32 and model.decay_dv == 205
    assert np.array_equal(model.calibration, ckpt.calibration)
    deployed = recalibrate(model, reference, ckpt.reference_place_ids)
    assert deployed.quantisation.calibration.startswith("deployed")
    assert deployed.quantisation.calibration_saturations == 0
    assert deployed.calibration.shape == ckpt.calibration.shape and deployed.calibration.sum() > 0
    assert np.array_equal(deployed.float_calibration, ckpt.calibration)
    reused = recalibrate(model, {}, ckpt.reference_place_ids, reuse_float_calibration=True)
    assert np.array_equal(reused.calibration, ckpt.calibration) and reused.quantisation.calibration == "float (reused)"
    with pytest.raises(InvalidValueError, match="reference places"):
        recalibrate(model, reference, ckpt.reference_place_ids[::-1])


def test_quantize_and_simulate_commands(tmp_path, capsys):
    ckpt, _ = small_checkpoint()
    source = save_checkpoint(tmp_path / "float.npz", ckpt)
    out = tmp_path / "models"
    assert (
        main(["quantize", str(source), "--bits", "8,3", "--per-neuron", "--scale", "mse", "--out", str(out), "--quiet"])
        == 0
    )
    table = capsys.readouterr().out
    assert "per-neuron" in table and "cal. saturations" in table
    names = sorted(p.name for p in out.iterdir())
    assert names == ["model_3bit_per-neuron_mse.npz", "model_8bit_per-neuron_mse.npz"]
    model_path = out / "model_8bit_per-neuron_mse.npz"
    assert load_fixed_point(model_path).quantisation.calibration.startswith("deployed")
    assert (
        main(
            [
                "simulate",
                str(model_path),
                "--query",
                "winter",
                "--k",
                "1,3",
                "--json",
                "--compare",
                str(source),
                "--quiet",
            ]
        )
        == 0
    )
    result = json.loads(capsys.readouterr().out)
    assert result["bits"] == 8 and result["saturations"] == 0
    assert {(r["calibration"], r["strategy"], r["k"]) for r in result["results"]} >= {
        ("deployed", "wprob", 1),
        ("deployed", "wprob", 3),
        ("float", "wprob", 1),
        ("float", "standard", 1),
    }
    assert {"accuracy", "r_at_100p", "auc_pr", "n_queries"} <= set(result["results"][0])
    assert result["winner_agreement"]["all_steps"] > 0.9
    assert main(["evaluate", str(source), "--query", "winter", "--k", "1,3", "--json", "--quiet"]) == 0
    evaluated = json.loads(capsys.readouterr().out)
    float_rows = evaluated["results"]
    assert result["cost"] == evaluated["cost"]  # the same spike trains: the same events per query
    assert [(r["strategy"], r["k"]) for r in float_rows] == [
        (r["strategy"], r["k"]) for r in result["results"] if r["calibration"] == "deployed"
    ]


def test_command_errors_are_clear(tmp_path, capsys):
    ckpt, _ = small_checkpoint()
    source = save_checkpoint(tmp_path / "float.npz", ckpt)
    assert main(["quantize", str(source), "--bits", "8,1", "--out", str(tmp_path / "m")]) == 2
    assert "unsupported weight bit width 1" in capsys.readouterr().err
    assert main(["quantize", str(source), "--fold-thresholds", "--per-tensor", "--out", str(tmp_path / "m")]) == 2
    assert "(--fold-thresholds) needs per-neuron scales" in capsys.readouterr().err
    assert (
        main(
            [
                "quantize",
                str(source),
                "--bits",
                "4",
                "--reuse-float-calibration",
                "--out",
                str(tmp_path / "m"),
                "--quiet",
            ]
        )
        == 0
    )
    capsys.readouterr()
    other = save_checkpoint(
        tmp_path / "other.npz", ckpt.__class__(**{**ckpt.__dict__, "thresholds": ckpt.thresholds + 1})
    )
    model = tmp_path / "m" / "model_4bit_per-neuron_max.npz"
    assert main(["simulate", str(model), "--query", "winter", "--compare", str(other)]) == 2
    assert "not the checkpoint this model was quantised from" in capsys.readouterr().err
    assert main(["simulate", str(tmp_path / "nope.npz"), "--query", "winter"]) == 2
    assert "no such fixed-point model file" in capsys.readouterr().err
