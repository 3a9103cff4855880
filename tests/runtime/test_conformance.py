"""The conformance harness: backends compared field by field, and that it catches one flipped spike or weight."""

import dataclasses

import numpy as np
import pytest
import torch

from vprsnn_export.checkpoint import checkpoint_sha256, load_checkpoint
from vprsnn_export.cli import main
from vprsnn_export.dataset import load_dataset
from vprsnn_export.encoding import query_spikes
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.export.quantize import quantize_checkpoint
from vprsnn_export.runs import SpikeRun
from vprsnn_export.runtime import conformance
from vprsnn_export.runtime.conformance import (
    Conformance,
    check_conformance,
    distribution_comparison,
    exact_comparison,
)
from vprsnn_export.runtime.exporting import write_targets
from vprsnn_export.targets.intsim import IntegerNetwork

TINY = ["--timesteps", "40", "--epochs", "2", "--neurons", "48"]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    folder = tmp_path_factory.mktemp("conformance")
    path = folder / "tiny.npz"
    assert main(["train", "--data", "synthetic:20", "--reference", "summer", "--out", str(path), "--quiet", *TINY]) == 0
    ckpt = load_checkpoint(path)
    data = load_dataset("synthetic:20", ["summer", "winter"], ckpt.config.preprocess)
    return path, ckpt, data


def cross_implementation(
    model: FixedPointModel, spikes: torch.Tensor, run: SpikeRun, folder, targets, reference_queries: int
) -> dict:
    written, skipped = write_targets(model, model, targets, folder, onnx_raster=True)
    result = check_conformance(model, spikes, run, written, reference_queries=reference_queries, skipped=skipped)
    assert Conformance.from_dict(result.to_dict()) == result  # the JSON form round-trips
    return result.to_dict()


# ---------------------------------------------------------------- exact comparisons


def test_exact_comparison_passes_identical_and_catches_one_flipped_bit():
    raster = np.random.default_rng(0).random((3, 10, 5)) > 0.7
    assert exact_comparison("raster", "a", raster, "b", raster.copy()).equal
    corrupt = raster.copy()
    corrupt[2, 7, 4] = ~corrupt[2, 7, 4]
    result = exact_comparison("raster", "a", raster, "b", torch.as_tensor(corrupt))
    assert not result.equal and result.n_differences == 1 and result.first_difference == [2, 7, 4]
    assert not exact_comparison("counts", "a", np.zeros((2, 3)), "b", np.zeros((3, 2))).equal
    assert not exact_comparison("saturations", "a", 0, "b", 1).equal


def test_distribution_comparison_allows_rounding_but_not_another_decision():
    p = np.array([[0.1, 0.6, 0.3], [0.5, 0.25, 0.25]])
    assert distribution_comparison("w", "a", p, "b", p + 1e-15).equal
    assert not distribution_comparison("w", "a", p, "b", p + 1e-9).equal  # beyond float64 rounding
    swapped = p.copy()
    swapped[0] = [0.1, 0.3, 0.6]
    result = distribution_comparison("w", "a", p, "b", swapped)
    assert not result.equal and result.n_differences == 1


@pytest.fixture(scope="module")
def model_and_spikes(tiny):
    path, ckpt, data = tiny
    model = quantize_checkpoint(ckpt, checkpoint_sha256(path), 4, per_neuron=True, scale_method="max")
    spikes = query_spikes(data.traversal("winter")[:6], data.place_ids[:6], "winter", ckpt.config)
    return model, spikes


def test_cross_implementation_is_exact(model_and_spikes, tmp_path):
    model, spikes = model_and_spikes
    run = IntegerNetwork(model).run(spikes, record=True)
    cross = cross_implementation(model, spikes, run, tmp_path, ("onnx", "nir", "loihi"), 2)
    assert cross["passed"] and cross["n_failed"] == 0 and cross["reference_queries"] == 2
    names = {c["check"].split(":")[0] for c in cross["checks"]}
    assert names == {"reference stepper", "ONNX (onnxruntime)", "NIR read back", "Loihi read back"}
    assert (tmp_path / "model.onnx").is_file() and (tmp_path / "model.nir").is_file() and (tmp_path / "loihi").is_dir()


def test_cross_implementation_catches_one_corrupted_spike(model_and_spikes, tmp_path):
    model, spikes = model_and_spikes
    run = IntegerNetwork(model).run(spikes, record=True)
    raster = run.raster.clone()
    raster[1, 5, 0] = ~raster[1, 5, 0]
    corrupt = dataclasses.replace(run, raster=raster)
    cross = cross_implementation(model, spikes, corrupt, tmp_path, ("onnx", "nir"), 2)
    failed = {c["check"] for c in cross["checks"] if not c["equal"]}
    assert not cross["passed"] and cross["n_failed"] == 3
    assert failed == {"reference stepper: raster", "ONNX (onnxruntime): raster", "NIR read back: raster"}


def test_cross_implementation_catches_a_corrupted_export(model_and_spikes, tmp_path, monkeypatch):
    model, spikes = model_and_spikes
    real = conformance.read_nir

    def tampered(path):
        rebuilt = real(path)
        mantissa = rebuilt.weight_mantissa.copy()
        mantissa[mantissa.argmax()] -= 1  # one weight one level lower
        return dataclasses.replace(rebuilt, weight_mantissa=mantissa)

    monkeypatch.setattr(conformance, "read_nir", tampered)
    run = IntegerNetwork(model).run(spikes, record=True)
    cross = cross_implementation(model, spikes, run, tmp_path, ("nir",), 0)
    failed = {c["check"] for c in cross["checks"] if not c["equal"]}
    assert "NIR read back: weight_mantissa" in failed and not cross["passed"]
