"""Deploying an ensemble of modules (issue 13): quantisation per module, every target, bit for bit.

A small ensemble (3 modules of 20 places, 8 neurons each, T = 16, 3 epochs) is trained once on
the synthetic route; every test quantises it (8/4/2 bits, per-neuron and per-tensor), writes the
targets, reads them back and requires the integer simulator, the reference stepper, onnxruntime
and the read-back files to agree exactly. The consumer and Lava runs are ``slow``.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch

from vprsnn_export.cli import main
from vprsnn_export.config import Config
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.export.model import FixedPointModel, load_fixed_point
from vprsnn_export.export.quantize import QuantiseOptions, quantize_checkpoint
from vprsnn_export.readout.regions import hyperactive_neurons
from vprsnn_export.readout.scoring import Readout
from vprsnn_export.readout.strategies import strategy_scores
from vprsnn_export.runtime.deployment import deploy
from vprsnn_export.runtime.exporting import ExportSource, export_and_check
from vprsnn_export.targets.intsim import simulate
from vprsnn_export.targets.loihi_budget import LOIHI1, LOIHI2, budget_table, core_budget
from vprsnn_export.targets.loihi_target import read_loihi, read_loihi_model, write_loihi
from vprsnn_export.targets.nir_read import read_nir
from vprsnn_export.targets.nir_runners import generic_consumer_raster, snntorch_consumer_raster
from vprsnn_export.targets.nir_target import apply_readout_rule, build_graph, write_nir
from vprsnn_export.targets.onnx_session import run_onnx_outputs
from vprsnn_export.targets.onnx_target import write_onnx
from vprsnn_export.targets.reference_stepper import reference_run
from vprsnn_export.trainer.pipeline import train_and_calibrate

MODULES, GROUP = 3, 8
ENSEMBLE = {
    "train.module_size": 20,
    "train.epochs": 3,
    "network.n_neurons": GROUP,
    "encoder.timesteps": 16,
}
RUN_LAVA = Path(__file__).resolve().parent / "lava_conformance" / "run_lava.py"


@pytest.fixture(scope="module", params=["ensemble", "module"])
def route(request):
    """(checkpoint, dataset) of the 3-module ensemble on synthetic:60 (about a second), for each WTA scope
    at inference (network.wta_scope: one winner per step over the ensemble, or one per module)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    cfg = Config().replace(**ENSEMBLE, **{"network.wta_scope": request.param})
    dataset = load_dataset("synthetic:60", ["summer", "winter"], cfg.preprocess)
    ckpt = train_and_calibrate(dataset, ["summer"], cfg, progress=False)
    torch.set_num_threads(threads)
    assert ckpt.weights.shape == (cfg.network.n_inputs, MODULES * GROUP)
    return ckpt, dataset


@pytest.fixture(scope="module")
def queries(route) -> torch.Tensor:
    """Winter queries of two places in every module (0, 7, 20, 27, 40, 47)."""
    ckpt, dataset = route
    index = np.array([0, 7, 20, 27, 40, 47])
    return query_spikes(dataset.traversal("winter")[index], dataset.place_ids[index], "winter", ckpt.config)


def quantised(route, bits: int, per_neuron: bool, fold: bool = False) -> FixedPointModel:
    return quantize_checkpoint(route[0], "0" * 64, bits, QuantiseOptions(per_neuron=per_neuron, fold_thresholds=fold))


def test_per_tensor_means_one_scale_per_module_and_the_report_has_every_module(route):
    for bits in (8, 4, 2):
        model = quantised(route, bits, per_neuron=False)
        per_module = model.scale_multiplier.reshape(MODULES, GROUP)
        assert np.all(per_module == per_module[:, :1])
        assert len(np.unique(per_module[:, 0])) > 1  # each module's weight tensor has its own scale
        for m in range(MODULES):  # the top level is used in every module: its own max-abs scale
            assert model.weight_mantissa[:, m * GROUP : (m + 1) * GROUP].max() == 2**bits - 1
        report = model.quantisation
        assert len(report.module_weight_relative_rmse) == MODULES and len(report.module_max_current) == MODULES
        assert max(report.module_max_current) == report.max_current and sum(report.module_weights_clipped) == 0
        neuron = quantised(route, bits, per_neuron=True)
        assert neuron.quantisation.module_weight_relative_rmse is not None
        assert max(neuron.quantisation.module_weight_relative_rmse) <= max(report.module_weight_relative_rmse)


def test_threshold_folding_gives_the_ensemble_one_integer_threshold(route):
    model = quantised(route, 4, per_neuron=True, fold=True)
    assert np.unique(model.threshold).size == 1


def test_the_per_module_report_survives_the_model_file(route, tmp_path):
    from vprsnn_export.export.model import save_fixed_point

    model = quantised(route, 4, per_neuron=False)
    loaded = load_fixed_point(save_fixed_point(tmp_path / "m.npz", model))
    assert loaded.quantisation == model.quantisation


def test_deployed_calibration_runs_the_whole_ensemble_on_the_integer_simulator(route):
    ckpt, dataset = route
    images = {"summer": dataset.traversal("summer")}
    model = deploy(ckpt, "0" * 64, 4, reference_images=images)
    assert model.calibration.shape == (MODULES * GROUP, 60)
    assert model.quantisation.calibration == "deployed (integer simulator)"
    # every place's T spikes per traversal: one winner per WTA group per step
    steps = ckpt.config.encoder.timesteps
    per_module = model.calibration.reshape(MODULES, GROUP, -1).sum(axis=1)
    assert np.all(per_module <= steps)
    if ckpt.config.network.wta_scope == "ensemble":
        assert np.all(model.calibration.sum(axis=0) <= steps) and np.any(per_module.min(axis=0) == 0)
    else:
        assert np.all(model.calibration.sum(axis=0) <= MODULES * steps)


@pytest.mark.parametrize("bits", [8, 4, 2])
@pytest.mark.parametrize("per_neuron", [True, False])
def test_every_target_runs_the_ensemble_bit_for_bit(route, queries, tmp_path, bits, per_neuron):
    model = quantised(route, bits, per_neuron)
    reference = simulate(model, queries, record=True)
    raster = reference.raster
    assert int(raster.reshape(*raster.shape[:2], MODULES, GROUP).sum(dim=3).max()) == 1  # one winner per module
    if model.config.network.wta_scope == "ensemble":
        assert int(raster.sum(dim=2).max()) == 1  # one winner per step over the whole ensemble
        assert len(np.unique(np.nonzero(raster.numpy())[2] // GROUP)) > 1  # the winners come from several modules
    else:
        assert int(raster.sum()) > raster.shape[0] * raster.shape[1]  # several modules spike in one step
    stepper = reference_run(model, queries.numpy())
    assert torch.equal(stepper.raster, raster) and torch.equal(stepper.counts, reference.counts)
    assert torch.equal(stepper.final_voltage, reference.final_voltage)

    onnx_run = run_onnx_outputs(write_onnx(model, tmp_path / "m.onnx", with_raster=True), queries)
    assert np.array_equal(onnx_run.raster, raster.numpy()) and np.array_equal(onnx_run.counts, reference.counts)

    nir_model = read_nir(write_nir(model, tmp_path / "m.nir"))
    write_loihi(model, tmp_path / "loihi")
    loihi_model = read_loihi_model(tmp_path / "loihi")
    for back in (nir_model, loihi_model):
        assert isinstance(back, FixedPointModel)
        for name in ("weight_mantissa", "scale_multiplier", "threshold", "calibration", "reference_place_ids"):
            assert np.array_equal(getattr(back, name), getattr(model, name)), name
        assert back.config == model.config and back.quantisation == model.quantisation
        assert torch.equal(simulate(back, queries, record=True).raster, raster)


def test_the_readout_rule_runs_per_module(route, queries, tmp_path):
    model = quantised(route, 4, per_neuron=True)
    graph = build_graph(model)
    rule = json.loads(graph.metadata["readout_rule"])
    groups = 1 if model.config.network.wta_scope == "ensemble" else MODULES
    assert rule["group_size"] == MODULES * GROUP // groups and rule["groups"] == groups
    assert graph.metadata["modules"] == MODULES and rule["scope"] == model.config.network.wta_scope
    populations = json.loads(graph.metadata["populations"])
    assert [p["neurons"] for p in populations] == [[0, 8], [8, 16], [16, 24]]
    assert [p["places"] for p in populations] == [[0, 20], [20, 40], [40, 60]]
    off = simulate(
        dataclasses.replace(model, config=model.config.replace(**{"network.wta": False})), queries, record=True
    )
    assert torch.equal(apply_readout_rule(graph, queries, off.raster), simulate(model, queries, record=True).raster)


def test_the_loihi_description_has_one_population_per_module(route, tmp_path):
    model = quantised(route, 2, per_neuron=True)
    write_loihi(model, tmp_path / "loihi")
    header = read_loihi(tmp_path / "loihi").header
    scope = model.config.network.wta_scope
    assert header["wta"]["group_size"] == (MODULES * GROUP if scope == "ensemble" else GROUP)
    assert header["wta"]["scope"] == scope
    assert [m["name"] for m in header["modules"]] == ["exc_0", "exc_1", "exc_2"]
    for m, module in enumerate(header["modules"]):
        own = slice(m * GROUP, (m + 1) * GROUP)
        assert module["neurons"] == [m * GROUP, (m + 1) * GROUP] and module["places"] == [20 * m, 20 * (m + 1)]
        assert module["vth_range"] == [int(model.threshold[own].min()), int(model.threshold[own].max())]
        assert module["current_bound"] == int(model.weight_mantissa[:, own].sum(axis=0).max())
    chips = {row["chip"]: row for row in header["resources"]}
    assert chips["Loihi 1"]["cores"] == MODULES and chips["Loihi 1"]["synapses"] == 1568 * MODULES * GROUP


def test_export_check_passes_on_an_ensemble(route, queries, tmp_path):
    ckpt = route[0]
    model = quantised(route, 4, per_neuron=True)
    source = ExportSource.of(model, "0" * 64)
    result = export_and_check(source, model, ("nir", "loihi", "onnx"), tmp_path / "x", spikes=queries)
    assert result.passed and result.checks is not None
    failed = [row for row in result.checks.rows if row.ok is False]
    assert not failed
    assert "ensemble of 3 modules" in result.consumers["onnx"]
    float_result = export_and_check(ExportSource.of(ckpt, "0" * 64), None, ("nir",), tmp_path / "f", spikes=queries)
    assert float_result.passed


def test_core_budget_of_the_shared_route():
    """24 modules of 100 places x 400 neurons x 1568 inputs (docs/targets.md §2.5)."""
    cores = {(b.chip, b.bits): (b.neurons_per_core, b.cores, b.chips) for b in budget_table(24, 400, 1568, (8, 4, 2))}
    assert cores == {
        ("Loihi 1", 8): (70, 144, 2),
        ("Loihi 1", 4): (128, 96, 1),
        ("Loihi 1", 2): (219, 48, 1),
        ("Loihi 2", 8): (125, 96, 1),
        ("Loihi 2", 4): (250, 48, 1),
        ("Loihi 2", 2): (400, 24, 1),
    }
    eight = core_budget(24, 400, 1568, 8, LOIHI1)
    assert eight.synapses == 15_052_800 and eight.synapse_bits_per_core <= LOIHI1.synapse_bits_per_core
    # one more neuron per core no longer fits: 71 synapses per axon need 640 + 64 bits
    assert 1568 * (9 * 64 + 128) > LOIHI1.synapse_bits_per_core
    assert core_budget(1, 10, 1568, 8, LOIHI2).neurons_per_core == 10


def test_loihi_cores_command_prints_the_table(capsys):
    assert main(["export", "--loihi-cores", "24x400x1568", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["loihi_cores"]
    assert [(r["chip"], r["bits"], r["cores"]) for r in rows][:3] == [
        ("Loihi 1", 8, 144),
        ("Loihi 1", 4, 96),
        ("Loihi 1", 2, 48),
    ]
    assert main(["export", "--loihi-cores", "24x400"]) == 2
    assert "MODULESxNEURONSxINPUTS" in capsys.readouterr().err


# --- slow: the field's consumers and Lava on an ensemble ----------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("bits", [8, 4, 2])
def test_nirtorch_and_snntorch_run_the_ensemble_with_the_grouped_rule(route, queries, tmp_path, bits):
    """Folded thresholds (one threshold, as snnTorch needs): each consumer + the rule == the simulator's raster."""
    model = quantised(route, bits, per_neuron=True, fold=True)
    graph = build_graph(model)
    expected = simulate(model, queries, record=True).raster
    off = simulate(
        dataclasses.replace(model, config=model.config.replace(**{"network.wta": False})), queries, record=True
    )
    for consumer in (generic_consumer_raster, snntorch_consumer_raster):
        candidates = consumer(graph, queries)
        assert torch.equal(candidates, off.raster), consumer.__name__
        assert torch.equal(apply_readout_rule(graph, queries, candidates), expected), consumer.__name__


@pytest.mark.slow
@pytest.mark.parametrize("bits", [8, 2])
def test_lava_wta_readout_runs_the_ensemble(route, queries, tmp_path, bits, lava_python):
    """The description in Lava with WtaReadout per module == the simulator's WTA-on raster."""
    model = quantised(route, bits, per_neuron=True)
    write_loihi(model, tmp_path / "desc")
    np.save(tmp_path / "spikes.npy", queries.numpy())
    done = subprocess.run(
        [str(lava_python), str(RUN_LAVA), "--wta", str(tmp_path / "desc"), str(tmp_path / "spikes.npy")]
        + [str(tmp_path / "raster.npy"), str(tmp_path / "candidates.npy")],
        capture_output=True,
        text=True,
        timeout=1800,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    winners = torch.from_numpy(np.load(tmp_path / "raster.npy").astype(bool))
    candidates = torch.from_numpy(np.load(tmp_path / "candidates.npy").astype(bool))
    off = dataclasses.replace(model, config=model.config.replace(**{"network.wta": False}))
    assert torch.equal(candidates, simulate(off, queries, record=True).raster)
    assert torch.equal(winners, simulate(model, queries, record=True).raster)


@pytest.mark.slow
def test_netx_runs_the_ensemble(route, queries, tmp_path, netx_python):
    """network.net of an ensemble (one dense layer of M n neurons) in netx == the simulator's WTA-off raster."""
    model = quantised(route, 4, per_neuron=True)
    write_loihi(model, tmp_path / "desc")
    np.save(tmp_path / "spikes.npy", queries.numpy())
    done = subprocess.run(
        [str(netx_python), str(RUN_LAVA), "--netx", str(tmp_path / "desc"), str(tmp_path / "spikes.npy")]
        + [str(tmp_path / "out.npy")],
        capture_output=True,
        text=True,
        timeout=1800,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    netx = torch.from_numpy(np.load(tmp_path / "out.npy").astype(bool))
    off = dataclasses.replace(model, config=model.config.replace(**{"network.wta": False}))
    assert torch.equal(netx, simulate(off, queries, record=True).raster)


def test_quantize_command_prints_the_modules(route, tmp_path, capsys):
    from vprsnn_export.io.checkpoint import save_checkpoint

    path = save_checkpoint(tmp_path / "ens.npz", route[0])
    args = ["quantize", str(path), "--bits", "4", "--per-tensor", "--reuse-float-calibration", "--quiet"]
    assert main([*args, "--out", str(tmp_path / "q")]) == 0
    assert "4 bits, 3 modules: rel. RMSE per module" in capsys.readouterr().out
    model = load_fixed_point(tmp_path / "q" / "model_4bit_per-tensor_max.npz")
    assert np.all(model.scale_multiplier.reshape(MODULES, GROUP).std(axis=1) == 0)


@pytest.mark.parametrize("outside_weight", [0.0, 0.5])
def test_the_onnx_wprob_head_reads_out_with_the_region_regularisation(route, queries, tmp_path, outside_weight):
    """The head embeds S~ (lambda outside each region, hyperactive rows zeroed) and drops silenced counts."""
    model = quantised(route, 8, per_neuron=True)
    model = dataclasses.replace(
        model,
        config=model.config.replace(
            **{"assignment.outside_weight": outside_weight, "assignment.hyperactive_share": 0.3}
        ),
    )
    onnx_run = run_onnx_outputs(write_onnx(model, tmp_path / "m.onnx"), queries)
    readout = Readout.of(model.calibration, model.config)
    assert readout.modules is not None and hyperactive_neurons(model.calibration, readout.modules).any()
    expected = readout.scores(onnx_run.counts)["wprob"]  # the rule silences someone here
    assert np.abs(onnx_run.wprob - expected).max() <= 1e-12
    plain = strategy_scores(model.calibration, onnx_run.counts, "wprob", model.config.assignment.gamma)
    assert np.abs(onnx_run.wprob - plain).max() > 1e-6  # and the rule changes the distribution
