"""NIR target: nir.read reads the files, read_nir rebuilds the network exactly, external consumers run them."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import h5py
import nir
import numpy as np
import pytest
import torch

from vprsnn_export.errors import InvalidValueError, ModelFileError
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.targets.intsim import simulate
from vprsnn_export.targets.nir_read import read_nir
from vprsnn_export.targets.nir_runners import generic_consumer_raster, snntorch_consumer_raster, spike_agreement
from vprsnn_export.targets.nir_target import DT_SECONDS, apply_readout_rule, build_graph, write_nir

NORDLAND = Path(__file__).resolve().parents[2].parent / "shared/data/nordland_64x32_summer_winter"


HISTORY = [{"epoch": 1, "mean_theta": 1.2}]  # a checkpoint's training history, carried through the file


def random_spikes(seed: int, n: int = 5, timesteps: int = 25, n_inputs: int = 16, p: float = 0.3) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return (torch.rand((n, timesteps, n_inputs), generator=generator) < p).to(torch.uint8)


def float_raster(ckpt: Checkpoint, spikes: torch.Tensor, wta: bool | None = None) -> torch.Tensor:
    cfg = ckpt.config if wta is None else ckpt.config.replace(**{"network.wta": wta})
    return (
        FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, cfg, torch.device("cpu"))
        .run(spikes, record=True)
        .raster
    )


def int_raster(model: FixedPointModel, spikes: torch.Tensor, wta: bool | None = None) -> torch.Tensor:
    if wta is not None:
        model = dataclasses.replace(model, config=model.config.replace(**{"network.wta": wta}))
    return simulate(model, spikes, record=True).raster


@pytest.mark.parametrize("bits,wta", [(8, True), (4, False), (2, True)])
def test_fixed_point_round_trip_is_exact(tmp_path, bits, wta, make_model):
    model = make_model(np.random.default_rng(bits), bits=bits, wta=wta)
    rebuilt = read_nir(write_nir(model, tmp_path / "m.nir"))
    assert isinstance(rebuilt, FixedPointModel)
    for f in dataclasses.fields(model):
        a, b = getattr(model, f.name), getattr(rebuilt, f.name)
        assert np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b, f.name
    spikes = random_spikes(bits)
    assert torch.equal(int_raster(model, spikes), int_raster(rebuilt, spikes))


@pytest.mark.parametrize("wta", [True, False])
def test_float_round_trip_is_exact(tmp_path, wta, make_checkpoint):
    ckpt = make_checkpoint(np.random.default_rng(1), wta=wta, history=HISTORY)
    rebuilt = read_nir(write_nir(ckpt, tmp_path / "f.nir", source_sha256="cd" * 32))
    assert isinstance(rebuilt, Checkpoint)
    assert np.array_equal(rebuilt.weights, ckpt.weights) and rebuilt.weights.dtype == np.float32
    assert np.array_equal(rebuilt.thresholds, ckpt.thresholds)
    assert rebuilt.config == ckpt.config and rebuilt.history == ckpt.history and rebuilt.data == ckpt.data
    spikes = random_spikes(2)
    assert torch.equal(float_raster(ckpt, spikes), float_raster(rebuilt, spikes))


def test_nir_read_sees_the_documented_graph(tmp_path, make_model):
    model = make_model(np.random.default_rng(3))
    graph = nir.read(write_nir(model, tmp_path / "m.nir", wta_inhibition=0.5, wta_node=True))
    assert isinstance(graph.nodes["linear"], nir.Linear) and graph.nodes["linear"].weight.shape == (6, 16)
    lif = graph.nodes["lif"]
    beta = (4096 - 205) / 4096
    np.testing.assert_allclose(lif.tau, DT_SECONDS / (1 - beta))
    np.testing.assert_allclose(lif.r, 1 / (1 - beta))
    assert np.array_equal(lif.v_threshold, model.threshold) and not np.any(lif.v_reset)
    assert ("lif", "wta") in graph.edges and ("wta", "lif") in graph.edges
    wta = graph.nodes["wta"].weight
    expected = -0.5 * model.threshold[:, None] * (1 - np.eye(6))
    assert np.array_equal(wta, expected.astype(np.float32))
    meta = graph.metadata
    assert meta["dt"] == DT_SECONDS and meta["bits"] == 8 and meta["timesteps"] == 20 and meta["wta"] == "on"
    assert "largest a_j * m_j" in meta["wta_rule"] and np.array_equal(
        meta["wta_score_multiplier"], model.scale_multiplier
    )


def test_the_default_graph_is_portable_and_states_its_readout_rule(tmp_path, make_model):
    graph = nir.read(write_nir(make_model(np.random.default_rng(3)), tmp_path / "m.nir"))
    assert sorted(graph.nodes) == ["input", "lif", "linear", "output"]
    rule = json.loads(graph.metadata["readout_rule"])
    assert rule["name"] == "vprsnn-hard-wta" and rule["version"] == 2 and "lowest index" in rule["winner"]
    assert rule["group_size"] == 6 and rule["groups"] == 1 and graph.metadata["modules"] == 1
    off = nir.read(write_nir(make_model(np.random.default_rng(3), wta=False), tmp_path / "off.nir"))
    assert json.loads(off.metadata["readout_rule"])["name"] == "none"


@pytest.mark.parametrize("bits", [8, 4, 2])
def test_readout_rule_on_the_wta_off_raster_gives_the_integer_network(tmp_path, bits, make_model):
    """Integer currents are exact: the rule applied to the WTA-off raster is the WTA-on raster, spike for spike."""
    model = make_model(np.random.default_rng(8), bits=bits)
    graph = nir.read(write_nir(model, tmp_path / "m.nir"))
    spikes = random_spikes(8, p=0.5)
    ruled = apply_readout_rule(graph, spikes, int_raster(model, spikes, wta=False))
    assert torch.equal(ruled, int_raster(model, spikes)) and int(ruled.sum()) > 0


def test_readout_rule_turns_a_consumer_raster_into_the_float_network(tmp_path, make_checkpoint):
    ckpt = make_checkpoint(np.random.default_rng(9), dyadic=True, history=HISTORY)
    graph = nir.read(write_nir(ckpt, tmp_path / "f.nir"))
    spikes = random_spikes(9)
    consumer = generic_consumer_raster(graph, spikes)
    assert not torch.equal(consumer, float_raster(ckpt, spikes))
    assert torch.equal(apply_readout_rule(graph, spikes, consumer), float_raster(ckpt, spikes))


def test_no_leak_becomes_an_if_node(tmp_path, make_model):
    model = make_model(np.random.default_rng(4), dv=0)
    path = write_nir(model, tmp_path / "if.nir")
    assert isinstance(nir.read(path).nodes["lif"], nir.IF)
    spikes = random_spikes(4)
    assert torch.equal(int_raster(model, spikes), int_raster(read_nir(path), spikes))


def test_generic_nirtorch_consumer_computes_the_wta_off_network(tmp_path, make_checkpoint):
    """Inhibition 0 and exact float sums (dyadic values): nirtorch with NIR's LIF equals the WTA-off network."""
    ckpt = make_checkpoint(np.random.default_rng(5), dyadic=True, history=HISTORY)
    graph = nir.read(write_nir(ckpt, tmp_path / "d.nir", wta_inhibition=0.0))
    spikes = random_spikes(5)
    consumer = generic_consumer_raster(graph, spikes)
    assert torch.equal(consumer, float_raster(ckpt, spikes, wta=False))
    with_wta = spike_agreement(float_raster(ckpt, spikes), consumer)
    assert with_wta["recall"] == 1.0 and with_wta["precision"] < 1.0  # WTA spikes are a subset of the candidates


def test_generic_consumer_on_a_fixed_point_file_is_close_to_the_integer_network(tmp_path, make_model):
    model = make_model(np.random.default_rng(6), bits=4)
    spikes = random_spikes(6)
    consumer = generic_consumer_raster(nir.read(write_nir(model, tmp_path / "m.nir", wta_inhibition=0.0)), spikes)
    agreement = spike_agreement(int_raster(model, spikes, wta=False), consumer)
    assert agreement["recall"] > 0.9 and agreement["precision"] > 0.9  # float vs round-toward-zero decay


def test_snntorch_importer_runs_a_single_threshold_file_without_the_wta_node(tmp_path, make_checkpoint):
    ckpt = make_checkpoint(np.random.default_rng(7), dyadic=True, uniform=True, history=HISTORY)
    graph = nir.read(write_nir(ckpt, tmp_path / "s.nir", wta_node=False))
    spikes = random_spikes(7)
    assert torch.equal(snntorch_consumer_raster(graph, spikes), float_raster(ckpt, spikes, wta=False))
    assert isinstance(read_nir(tmp_path / "s.nir"), Checkpoint)


def test_writer_validates_its_input(tmp_path, make_model, make_checkpoint):
    model = make_model(np.random.default_rng(8))
    with pytest.raises(ModelFileError, match="weight_mantissa"):
        write_nir(dataclasses.replace(model, weight_mantissa=model.weight_mantissa + 300), tmp_path / "x.nir")
    ckpt = make_checkpoint(np.random.default_rng(8), history=HISTORY)
    with pytest.raises(ModelFileError, match="NaN"):
        write_nir(dataclasses.replace(ckpt, thresholds=np.full(6, np.nan, dtype=np.float32)), tmp_path / "x.nir")
    with pytest.raises(InvalidValueError, match="wta_inhibition"):
        build_graph(model, wta_inhibition=-1.0)
    assert list(tmp_path.iterdir()) == []


def test_reader_rejects_missing_truncated_foreign_and_tampered_files(tmp_path, make_model):
    with pytest.raises(ModelFileError, match="no such NIR file"):
        read_nir(tmp_path / "absent.nir")
    path = write_nir(make_model(np.random.default_rng(9)), tmp_path / "m.nir")
    truncated = tmp_path / "cut.nir"
    truncated.write_bytes(path.read_bytes()[:2000])
    with pytest.raises(ModelFileError, match="cut.nir.*truncated or corrupt"):
        read_nir(truncated)
    foreign = nir.NIRGraph.from_list(nir.Linear(weight=np.ones((2, 3), dtype=np.float32)))
    nir.write(tmp_path / "foreign.nir", foreign)
    with pytest.raises(ModelFileError, match="not a vprsnn NIR export"):
        read_nir(tmp_path / "foreign.nir")
    tampered = tmp_path / "tampered.nir"
    tampered.write_bytes(path.read_bytes())
    with h5py.File(tampered, "r+") as f:
        f["node/nodes/lif/tau"][...] = 1.0
    with pytest.raises(ModelFileError, match="tau/r disagree"):
        read_nir(tampered)
    fractional = tmp_path / "fractional.nir"
    fractional.write_bytes(path.read_bytes())
    with h5py.File(fractional, "r+") as f:
        f["node/nodes/linear/weight"][0, 0] = 0.5
    with pytest.raises(ModelFileError, match="integers"):
        read_nir(fractional)


def test_spike_agreement_counts_subsets_and_top1():
    reference = torch.zeros((2, 3, 4), dtype=torch.bool)
    reference[0, 0, 1] = reference[1, 2, 3] = True
    consumer = reference.clone()
    consumer[0, 0, 2] = True
    result = spike_agreement(reference, consumer)
    assert result["recall"] == 1.0 and result["precision"] == pytest.approx(2 / 3)
    assert result["exact_steps"] == pytest.approx(5 / 6) and result["top1_neuron"] == 1.0
