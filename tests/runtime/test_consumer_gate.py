"""The NIR consumer gate: export --check fails a file whose float consumers decide otherwise than the network.

The model is built so that the integer decay's truncation moves a crossing (the cause the gate
exists for): neuron 0 gets a = 27 per step and theta = 77. The integer network (voltage in
mantissa units * 2**6, decay V <- trunc(V * 3891 / 4096)) reaches 77 * 64 exactly at the third
step (no spike) and spikes at the fourth: 6 spikes in T = 24. NIR's LIF computes v = 27, 52.65,
77.01 (spike): one every 3 steps, 8 spikes. Neuron 1 (a = 78 > theta) spikes at 7 chosen steps in
both. The calibration maps neuron 0 to place 0 and neuron 1 to place 1, so the network decides
place 1 (7 > 6) and every float consumer place 0 (8 > 7). Without the leak (dv = 0, an IF node)
both compute the same.
"""

from __future__ import annotations

import dataclasses
import json

import nir
import numpy as np
import pytest
import torch

from vprsnn_export.config import preset
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.runtime.consumer_gate import consumer_gate
from vprsnn_export.runtime.exporting import ExportSource, export_and_check
from vprsnn_export.targets.intsim import simulate
from vprsnn_export.targets.nir_consumers import run_consumer
from vprsnn_export.targets.nir_semantics import LEAKY_DECISION_TOLERANCE
from vprsnn_export.targets.nir_target import write_nir

T = 24
NEURON_1_STEPS = (1, 4, 8, 11, 15, 18, 21)


def gate_model(decay_dv: int = 205) -> FixedPointModel:
    cfg = preset("paper").replace(
        **{
            "preprocess.image_size": 4,
            "preprocess.patch_size": 1,
            "network.n_inputs": 16,
            "network.n_neurons": 2,
            "network.wta": False,
            "encoder.timesteps": T,
        }
    )
    weights = np.zeros((16, 2), dtype=np.int32)
    weights[0, 0], weights[1, 1] = 27, 78
    return FixedPointModel(
        bits=8,
        weight_mantissa=weights,
        scale_multiplier=np.ones(2, dtype=np.int32),
        scale_exponent=-8,
        threshold=np.full(2, 77, dtype=np.int32),
        decay_dv=decay_dv,
        config=cfg,
        calibration=np.array([[10, 0], [0, 10]], dtype=np.int64),
        float_calibration=np.array([[10, 0], [0, 10]], dtype=np.int64),
        reference_place_ids=np.array([0, 1], dtype=np.int64),
        reference_traversals=["summer"],
        quantisation={"per_neuron": True, "scale_method": "max"},
        source_sha256="cd" * 32,
        data={"source": "synthetic"},
    )


def gate_spikes() -> torch.Tensor:
    spikes = torch.zeros((2, T, 16), dtype=torch.uint8)
    spikes[:, :, 0] = 1
    spikes[:, list(NEURON_1_STEPS), 1] = 1
    return spikes


def test_the_model_is_what_the_docstring_says(tmp_path):
    model, spikes = gate_model(), gate_spikes()
    counts = simulate(model, spikes).counts
    assert counts[0].tolist() == [6, 7]
    graph = nir.read(write_nir(model, tmp_path / "m.nir"))
    assert run_consumer("nir-spec-f64", graph, spikes).sum(dim=1)[0].tolist() == [8, 7]


def test_export_check_fails_a_file_whose_consumers_disagree_beyond_tolerance(tmp_path):
    model = gate_model()
    result = export_and_check(ExportSource.of(model, "ef" * 32), model, ["nir"], tmp_path / "x", spikes=gate_spikes())
    assert result.checks is not None and not result.passed
    gate = [r for r in result.checks.rows if "readout rule" in r.check and r.ok is not None]
    assert gate and all(r.ok is False for r in gate if "refuses" not in r.detail)
    assert f"tolerance {LEAKY_DECISION_TOLERANCE:.1%}" in gate[0].detail and "0.0% of 2 decisions" in gate[0].detail
    manifest = json.loads((tmp_path / "x" / "export.json").read_text())
    assert manifest["checks"]["passed"] is False
    assert any(
        "decision agreement" in row["check"] or "decisions agree" in row["detail"] for row in manifest["checks"]["rows"]
    )


def test_the_non_leaky_model_is_exact_in_every_float_consumer_and_passes(tmp_path):
    model = gate_model(decay_dv=0)
    graph = nir.read(write_nir(model, tmp_path / "m.nir"))
    assert isinstance(graph.nodes["lif"], nir.IF)
    statement = json.loads(graph.metadata["float_consumers"])
    assert statement["exact"] is True and statement["decision_tolerance"] == 1.0
    spikes = gate_spikes()
    rows = consumer_gate(tmp_path / "m.nir", model, simulate(model, spikes, record=True).raster, spikes)
    assert rows and all(r.passed for r in rows)
    assert all("100.0% of 2" in r.detail for r in rows if "refuses" not in r.detail)
    result = export_and_check(ExportSource.of(model, "ef" * 32), model, ["nir"], tmp_path / "x", spikes=spikes)
    assert result.passed


def test_a_stated_tolerance_below_the_measured_agreement_passes(tmp_path):
    model = gate_model()
    spikes = gate_spikes()
    path = write_nir(model, tmp_path / "m.nir")
    raster = simulate(model, spikes, record=True).raster
    assert all(r.passed for r in consumer_gate(path, model, raster, spikes, tolerance=0.0))
    assert not all(r.passed for r in consumer_gate(path, model, raster, spikes, tolerance=0.5))


def test_the_file_states_its_integer_semantics_machine_readably(tmp_path):
    graph = nir.read(write_nir(gate_model(), tmp_path / "m.nir"))
    semantics = json.loads(graph.metadata["integer_semantics"])
    assert semantics["decay"] == {
        "divisor": 4096,
        "equation": "V <- trunc_toward_zero(V * multiplier / divisor) + (a << voltage_shift)",
        "multiplier": 3891,
        "rounding": "toward_zero",
    }
    assert semantics["reset"]["value"] == 0 and semantics["saturation"]["max"] == 2**23 - 1
    statement = json.loads(graph.metadata["float_consumers"])
    assert statement["exact"] is False and "toward zero" in statement["cause"]


def test_a_tolerance_outside_zero_to_one_is_refused(tmp_path):
    from vprsnn_export.errors import InvalidValueError

    model = gate_model()
    path = write_nir(model, tmp_path / "m.nir")
    with pytest.raises(InvalidValueError, match="tolerance"):
        consumer_gate(path, model, torch.zeros((2, T, 2), dtype=torch.bool), gate_spikes(), tolerance=1.5)


def test_the_gate_uses_the_network_raster_it_is_given(tmp_path):
    """A network raster with neuron 1 silenced decides place 0 like the consumers: the gate then passes."""
    model = gate_model()
    spikes = gate_spikes()
    raster = simulate(dataclasses.replace(model), spikes, record=True).raster.clone()
    raster[..., 1] = False
    assert all(r.passed for r in consumer_gate(write_nir(model, tmp_path / "m.nir"), model, raster, spikes))
