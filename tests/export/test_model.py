"""The fixed-point model file: round trip, self-description and validation errors."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vprsnn_export.config import Config, preset
from vprsnn_export.errors import InvalidValueError, ModelFileError
from vprsnn_export.export.model import (
    FORMAT_VERSION,
    QuantisationReport,
    check_bits,
    decay_mantissa,
    load_fixed_point,
    save_fixed_point,
)
from vprsnn_export.export.quantize import QuantiseOptions, quantize_checkpoint
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.io.fileio import read_container, write_container

SMALL = {"preprocess.image_size": 4, "preprocess.patch_size": 2, "network.n_inputs": 16, "network.n_neurons": 5}


def small_model(bits: int = 4, per_neuron: bool = True, fold: bool = False):
    cfg = preset("paper").replace(**SMALL)
    rng = np.random.default_rng(3)
    ckpt = Checkpoint(
        config=cfg,
        weights=rng.random((16, 5)).astype(np.float32) * 0.4,
        thresholds=rng.uniform(0.6, 2.0, 5).astype(np.float32),
        calibration=rng.integers(0, 9, (5, 3)),
        reference_place_ids=np.array([4, 7, 9]),
        reference_traversals=["summer"],
        data={"source": "synthetic:10"},
    )
    return quantize_checkpoint(ckpt, "ab" * 32, bits, QuantiseOptions(per_neuron=per_neuron, fold_thresholds=fold))


def resave(path, tmp_path, *, meta=None, **arrays):
    """Rewrite a saved model with some header fields or arrays replaced (bypassing validation)."""
    header, stored = read_container(path, "fixed-point model")
    header.update(meta or {})
    stored.update(arrays)
    return write_container(tmp_path / "tampered.npz", header, stored)


def test_round_trip_keeps_every_array_and_field(tmp_path):
    model = small_model(fold=True)
    loaded = load_fixed_point(save_fixed_point(tmp_path / "m.npz", model))
    for name in (
        "weight_mantissa",
        "scale_multiplier",
        "threshold",
        "calibration",
        "float_calibration",
        "reference_place_ids",
    ):
        assert np.array_equal(getattr(loaded, name), getattr(model, name)), name
    for name in (
        "bits",
        "scale_exponent",
        "decay_dv",
        "source_sha256",
        "reference_traversals",
        "voltage_shift",
        "voltage_bits",
    ):
        assert getattr(loaded, name) == getattr(model, name), name
    assert loaded.config == model.config
    assert loaded.quantisation == model.quantisation
    assert list(tmp_path.iterdir()) == [tmp_path / "m.npz"]  # no temporary file left behind


def test_header_describes_widths_rounding_scales_and_encoder(tmp_path):
    header, _ = read_container(save_fixed_point(tmp_path / "m.npz", small_model()), "fixed-point model")
    assert header["format_version"] == FORMAT_VERSION and header["bits"] == 4
    assert header["config"]["encoder"]["timesteps"] == Config().encoder.timesteps
    assert header["quantisation"]["rounding"] and header["quantisation"]["scale_method"] == "max"
    assert {"weights", "decay", "voltage", "candidates", "wta", "reset"} <= set(header["arithmetic"])
    assert header["decay_dv"] == decay_mantissa(0.95) == 205


@pytest.mark.parametrize("bits", [1, 9, 16])
def test_unsupported_bit_width_is_an_option_error(bits):
    with pytest.raises(InvalidValueError, match="unsupported weight bit width"):
        check_bits(bits)


def test_mantissa_out_of_range_is_refused_on_save_and_load(tmp_path):
    model = small_model(bits=2)
    bad = model.weight_mantissa.copy()
    bad[0, 0] = 4  # 2-bit mantissas stop at 3
    with pytest.raises(ModelFileError, match="weight_mantissa values"):
        save_fixed_point(tmp_path / "m.npz", dataclasses.replace(model, weight_mantissa=bad))
    path = save_fixed_point(tmp_path / "m.npz", model)
    with pytest.raises(ModelFileError, match=r"tampered\.npz: weight_mantissa values"):
        load_fixed_point(resave(path, tmp_path, weight_mantissa=bad))


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("threshold", np.zeros(5, dtype=np.int32), "threshold values"),
        ("threshold", np.full(5, 1 << 17, dtype=np.int32), "threshold values"),
        ("scale_multiplier", np.zeros(5, dtype=np.int32), "scale_multiplier values"),
        ("weight_mantissa", np.zeros((16, 4), dtype=np.int32), "weight_mantissa has shape"),
        ("threshold", np.ones(6, dtype=np.int32), "threshold has shape"),
        ("weight_mantissa", np.zeros((16, 5), dtype=np.float32), "expected integers"),
        ("calibration", np.zeros((5, 2), dtype=np.int64), "calibration must"),
        ("calibration", -np.ones((5, 3), dtype=np.int64), "calibration must"),
    ],
)
def test_bad_arrays_are_refused_on_load(tmp_path, field, value, message):
    path = save_fixed_point(tmp_path / "m.npz", small_model())
    with pytest.raises(ModelFileError, match=message):
        load_fixed_point(resave(path, tmp_path, **{field: value}))


@pytest.mark.parametrize(
    ("meta", "message"),
    [
        ({"bits": 9}, "unsupported weight bit width 9"),
        ({"bits": 1}, "unsupported weight bit width 1"),
        ({"format_version": 99}, "unsupported fixed-point format version"),
        ({"format": "vprsnn-checkpoint"}, "not a vprsnn fixed-point model"),
        ({"decay_dv": 4096}, "decay_dv 4096 does not fit 12 bits"),
        ({"voltage_bits": 32}, "unsupported voltage format"),
        ({"config": {"network": {"bogus": 1}}}, "invalid fixed-point header"),
        ({"bits": 8.5}, "bits must be an integer"),
        ({"decay_dv": 204.5}, "decay_dv must be an integer"),
        ({"scale_exponent": 40}, "scale_exponent 40 is outside"),
        ({"scale_exponent": 10**30}, "is outside"),
        ({"source_sha256": [1, 2]}, "source_sha256 must be"),
        ({"arithmetic": [1]}, "must be mappings"),
        ({"reference_traversals": "summer"}, "reference_traversals must be"),
        ({"data": {"source": 5}}, "data must be a mapping"),
        ({"package_version": [1]}, "package_version must be"),
    ],
)
def test_bad_headers_are_refused(tmp_path, meta, message):
    path = save_fixed_point(tmp_path / "m.npz", small_model(bits=8))
    with pytest.raises(ModelFileError, match=message):
        load_fixed_point(resave(path, tmp_path, meta=meta))


def test_scheme_consistency_is_checked(tmp_path):
    per_tensor = save_fixed_point(tmp_path / "t.npz", small_model(per_neuron=False))
    with pytest.raises(ModelFileError, match="unequal scale multipliers"):
        load_fixed_point(resave(per_tensor, tmp_path, scale_multiplier=np.arange(1, 6, dtype=np.int32)))
    folded = save_fixed_point(tmp_path / "f.npz", small_model(fold=True))
    with pytest.raises(ModelFileError, match="unequal integer thresholds"):
        load_fixed_point(resave(folded, tmp_path, threshold=np.arange(1, 6, dtype=np.int32)))


def test_truncated_missing_and_foreign_files(tmp_path):
    path = save_fixed_point(tmp_path / "m.npz", small_model())
    raw = path.read_bytes()
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ModelFileError, match=r"truncated\.npz: not a readable fixed-point model"):
        load_fixed_point(truncated)
    with pytest.raises(ModelFileError, match="no such fixed-point model file"):
        load_fixed_point(tmp_path / "absent.npz")
    header, arrays = read_container(path, "fixed-point model")
    del arrays["threshold"]
    with pytest.raises(ModelFileError, match="lacks arrays"):
        load_fixed_point(write_container(tmp_path / "partial.npz", header, arrays))


#: The ``quantisation`` object of a header written before QuantisationReport existed (a plain dict).
OLD_QUANTISATION = {
    "weight_max_abs_error": 0.0123,
    "weight_rmse": 0.004,
    "weight_relative_rmse": 0.02,
    "weights_clipped": 0,
    "threshold_max_relative_error": 0.001,
    "thresholds_clipped": 0,
    "max_current": 60,
    "bits": 4,
    "per_neuron": True,
    "scale_method": "max",
    "threshold_folding": False,
    "shared_threshold": None,
    "rounding": "round to nearest, ties up: floor(x + 1/2), then clip to the width",
    "scale_exponent": -20,
    "scale_multiplier_range": [40000, 65535],
    "threshold_range": [10, 300],
    "calibration": "deployed (integer simulator)",
    "calibration_saturations": 0,
}


def test_quantisation_report_round_trips_and_keeps_unknown_keys():
    report = QuantisationReport.from_dict(OLD_QUANTISATION)
    assert report.per_neuron is True and report.scale_multiplier_range == (40000, 65535)
    assert report.to_dict() == OLD_QUANTISATION
    assert QuantisationReport.from_dict(report.to_dict()) == report
    partial = QuantisationReport.from_dict({"per_neuron": False, "made_up_later": [1, 2]})
    assert partial.bits is None and partial.extra == {"made_up_later": [1, 2]}
    assert partial.to_dict()["made_up_later"] == [1, 2]
    with pytest.raises(TypeError):
        QuantisationReport.from_dict(["not", "an", "object"])


def test_model_files_with_an_old_quantisation_header_load(tmp_path):
    path = save_fixed_point(tmp_path / "m.npz", small_model())
    old = resave(path, tmp_path, meta={"quantisation": dict(OLD_QUANTISATION)})
    loaded = load_fixed_point(old)
    assert isinstance(loaded.quantisation, QuantisationReport)
    assert loaded.quantisation.calibration == "deployed (integer simulator)" and loaded.quantisation.max_current == 60
    header, _ = read_container(save_fixed_point(tmp_path / "again.npz", loaded), "fixed-point model")
    assert header["quantisation"] == OLD_QUANTISATION  # written back unchanged
    bad = resave(path, tmp_path, meta={"quantisation": "per-neuron"})
    with pytest.raises(ModelFileError, match="invalid fixed-point header"):
        load_fixed_point(bad)
