"""ONNX target: onnxruntime against the integer simulator (the contract), file handling, the export command."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vprsnn_export.cli import main
from vprsnn_export.config import preset
from vprsnn_export.errors import InvalidValueError, ModelFileError
from vprsnn_export.export.model import FixedPointModel, save_fixed_point
from vprsnn_export.export.quantize import QuantiseOptions
from vprsnn_export.io.checkpoint import Checkpoint, save_checkpoint
from vprsnn_export.network.runs import Backend
from vprsnn_export.readout.assignment import weighted_matrix
from vprsnn_export.readout.strategies import strategy_scores
from vprsnn_export.targets.intsim import simulate
from vprsnn_export.targets.onnx_session import OnnxBackend, read_onnx, run_onnx, run_onnx_outputs
from vprsnn_export.targets.onnx_target import (
    IR_VERSION,
    OPSET,
    build_onnx,
    readout_calibration,
    readout_matrix_nodes,
    write_onnx,
)

NORDLAND = Path(__file__).resolve().parents[2].parent / "shared/data/nordland_64x32_summer_winter"


def make_model(
    rng,
    *,
    n_inputs=16,
    n_neurons=6,
    bits=8,
    wta=True,
    isolation=True,
    thresholds=(50, 600),
    dv=205,
    multipliers=(1, 2**16),
    places=4,
    timesteps=20,
) -> FixedPointModel:
    side = int(round(n_inputs**0.5))
    cfg = preset("paper").replace(
        **{
            "preprocess.image_size": side,
            "preprocess.patch_size": 1,
            "network.n_inputs": n_inputs,
            "network.n_neurons": n_neurons,
            "network.wta": wta,
            "network.state_isolation": isolation,
            "encoder.timesteps": timesteps,
        }
    )
    return FixedPointModel(
        bits=bits,
        weight_mantissa=rng.integers(0, 2**bits, (n_inputs, n_neurons)).astype(np.int32),
        scale_multiplier=rng.integers(*multipliers, n_neurons).astype(np.int32),
        scale_exponent=-20,
        threshold=rng.integers(*thresholds, n_neurons).astype(np.int32),
        decay_dv=dv,
        config=cfg,
        calibration=rng.integers(0, 4, (n_neurons, places)).astype(np.int64),
        float_calibration=rng.integers(0, 4, (n_neurons, places)).astype(np.int64),
        reference_place_ids=np.arange(places, dtype=np.int64),
        reference_traversals=["summer"],
        quantisation={"per_neuron": True},
        source_sha256="0" * 64,
    )


def random_spikes(seed: int, n: int, timesteps: int, n_inputs: int, p: float = 0.3) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return (torch.rand((n, timesteps, n_inputs), generator=generator) < p).to(torch.uint8)


def assert_identical(model: FixedPointModel, spikes: torch.Tensor, path: Path) -> None:
    write_onnx(model, path, with_raster=True)
    out = run_onnx_outputs(path, spikes, batch=3)
    expected = simulate(model, spikes, record=True)
    assert np.array_equal(out.counts, expected.counts.numpy())
    assert np.array_equal(out.raster, expected.raster.numpy())
    assert int(out.saturations.sum()) == expected.saturations
    wprob = strategy_scores(model.calibration, expected.counts.numpy(), "wprob", model.config.assignment.gamma)
    np.testing.assert_allclose(out.wprob, wprob, rtol=1e-12, atol=1e-15)


def test_onnx_backend_returns_a_spike_run(tmp_path):
    model = make_model(np.random.default_rng(5))
    spikes = random_spikes(5, 4, 20, 16)
    backend = OnnxBackend(write_onnx(model, tmp_path / "m.onnx", with_raster=True), batch=3)
    assert isinstance(backend, Backend) and backend.name == "onnxruntime"
    run = backend.run(spikes, record=True)
    expected = simulate(model, spikes, record=True)
    assert torch.equal(run.counts, expected.counts) and torch.equal(run.raster, expected.raster)
    assert run.saturations == expected.saturations and run.wprob is not None and run.wprob.shape[0] == 4
    assert run.candidates_per_step is None and run.final_voltage is None  # the graph has no such outputs
    bare = OnnxBackend(write_onnx(model, tmp_path / "bare.onnx", with_wprob=False)).run(spikes)
    assert bare.raster is None and bare.wprob is None and torch.equal(bare.counts, expected.counts)


@pytest.mark.parametrize("bits", [2, 4, 8])
@pytest.mark.parametrize("wta", [True, False])
def test_onnxruntime_matches_the_integer_simulator(tmp_path, bits, wta):
    model = make_model(np.random.default_rng(bits), bits=bits, wta=wta, timesteps=25)
    assert_identical(model, random_spikes(bits, 7, 25, 16), tmp_path / "m.onnx")


def test_saturation_is_clipped_and_counted_like_the_simulator(tmp_path):
    rng = np.random.default_rng(3)
    model = make_model(rng, n_inputs=64, bits=8, thresholds=(131000, 131071), dv=0, timesteps=60)
    spikes = random_spikes(3, 4, 60, 64, p=0.9)
    assert simulate(model, spikes).saturations > 0
    assert_identical(model, spikes, tmp_path / "sat.onnx")


def test_wta_ties_go_to_the_lowest_index(tmp_path):
    model = make_model(np.random.default_rng(4), n_neurons=5, multipliers=(7, 8), thresholds=(1, 2), timesteps=10)
    model.weight_mantissa[:] = model.weight_mantissa[:, :1]  # identical columns: equal scores every step
    spikes = random_spikes(4, 3, 10, 16)
    write_onnx(model, tmp_path / "tie.onnx")
    counts = run_onnx(tmp_path / "tie.onnx", spikes)
    assert counts[:, 1:].sum() == 0 and counts[:, 0].sum() > 0
    assert np.array_equal(counts, simulate(model, spikes).counts.numpy())


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    seed=st.integers(0, 2**32 - 1),
    bits=st.integers(2, 8),
    wta=st.booleans(),
    dv=st.integers(0, 4095),
    n_neurons=st.integers(1, 7),
    small_multipliers=st.booleans(),
)
def test_property_onnx_equals_simulator(tmp_path, seed, bits, wta, dv, n_neurons, small_multipliers):
    rng = np.random.default_rng(seed)
    model = make_model(
        rng,
        n_neurons=n_neurons,
        bits=bits,
        wta=wta,
        dv=dv,
        multipliers=(1, 3) if small_multipliers else (1, 2**16),
        timesteps=15,
    )
    assert_identical(model, random_spikes(seed % 1000, 4, 15, 16, p=float(rng.uniform(0.05, 0.9))), tmp_path / "p.onnx")


def test_graph_is_checked_ir10_and_self_describing(tmp_path):
    model = make_model(np.random.default_rng(5))
    path = write_onnx(model, tmp_path / "m.onnx")
    loaded = onnx.load(str(path))
    onnx.checker.check_model(loaded, full_check=True)
    assert loaded.ir_version == IR_VERSION == 10
    assert max(o.version for o in loaded.opset_import) <= 26
    ops = {node.op_type for node in loaded.graph.node}
    assert {"MatMulInteger", "Scan"} <= ops
    inputs = {i.name: i for i in loaded.graph.input}
    assert inputs["spikes"].type.tensor_type.elem_type == onnx.TensorProto.UINT8
    props = {p.key: p.value for p in loaded.metadata_props}
    assert props["vprsnn.bits"] == "8" and props["vprsnn.decay_dv"] == "205"


def initializers(model: onnx.ModelProto) -> dict[str, onnx.TensorProto]:
    return {t.name: t for t in model.graph.initializer}


@pytest.mark.parametrize("bits", [2, 3, 4, 5, 6, 7, 8])
def test_weights_take_about_bits_per_synapse(tmp_path, bits):
    model = make_model(np.random.default_rng(bits), n_inputs=49, n_neurons=5, bits=bits)
    graph = build_onnx(model)
    inits = initializers(graph)
    payload = (49 * 5 * bits + 7) // 8
    if bits == 8:
        stored = inits["weight_mantissa"]
        assert stored.data_type == onnx.TensorProto.UINT8 and len(stored.raw_data) == 49 * 5
    else:
        stored = inits["weight_packed"]
        kind = onnx.TensorProto.UINT4 if bits == 4 else onnx.TensorProto.UINT8
        assert stored.data_type == kind and len(stored.raw_data) == payload
    props = {p.key: p.value for p in graph.metadata_props}
    assert props["vprsnn.weight_storage"].startswith({8: "uint8", 4: "uint4"}.get(bits, "lsb-first-bitstream"))
    assert_identical(model, random_spikes(bits, 5, 20, 49), tmp_path / "w.onnx")


def run_readout_matrices(model: FixedPointModel) -> list[np.ndarray]:
    """The head's derived S^R, S'' and 1 / colsum(S^R), as onnxruntime computes them."""
    import onnxruntime as ort

    nodes, inits = readout_matrix_nodes(model, readout_calibration(model)[0])
    n, places = model.calibration.shape
    graph = onnx.helper.make_graph(
        nodes,
        "readout_matrices",
        [],
        [
            onnx.helper.make_tensor_value_info("s_r", onnx.TensorProto.DOUBLE, [n, places]),
            onnx.helper.make_tensor_value_info("s_double_prime", onnx.TensorProto.DOUBLE, [n, places]),
            onnx.helper.make_tensor_value_info("inv_colsum", onnx.TensorProto.DOUBLE, [1, places]),
        ],
        inits,
    )
    proto = onnx.helper.make_model(graph, opset_imports=[onnx.helper.make_opsetid("", OPSET)], ir_version=IR_VERSION)
    onnx.checker.check_model(proto, full_check=True)
    return ort.InferenceSession(proto.SerializeToString(), providers=["CPUExecutionProvider"]).run(None, {})


@pytest.mark.parametrize("sparse", [True, False])
@pytest.mark.parametrize("gamma", [0.0, 0.3, 1.0])
def test_readout_matrices_are_derived_in_graph_bit_for_bit(sparse, gamma):
    """S^R stored as narrow integers (dense or non-zeros only); S'' and 1/colsum equal the float64 constants exactly."""
    rng = np.random.default_rng(13)
    model = make_model(rng, n_neurons=40, places=30)
    counts = rng.integers(0, 301, (40, 30)) * (rng.random((40, 30)) < (0.05 if sparse else 0.9))
    counts[3] = 0  # a silent neuron
    counts[:, 4] = 0  # a place no neuron saw
    model = dataclasses.replace(model, calibration=counts.astype(np.int64))
    model.config = model.config.replace(**{"assignment.gamma": gamma})
    s_r, s_double_prime, inv_colsum = run_readout_matrices(model)
    sr = counts.astype(np.float64)
    colsum = sr.sum(axis=0)
    assert np.array_equal(s_r, sr)
    assert np.array_equal(s_double_prime, weighted_matrix(sr, gamma))
    assert np.array_equal(inv_colsum[0], np.where(colsum > 0, 1.0 / np.where(colsum > 0, colsum, 1.0), 0.0))
    stored = initializers(build_onnx(model))
    names = {"s_r_values", "s_r_positions"} if sparse else {"s_r_counts"}
    assert names <= set(stored) and all(
        onnx.helper.tensor_dtype_to_np_dtype(stored[k].data_type).itemsize == 2 for k in names
    )
    assert not any(t.data_type == onnx.TensorProto.DOUBLE and len(t.dims) for t in stored.values())


def test_writer_refuses_invalid_models_and_writes_nothing(tmp_path):
    model = make_model(np.random.default_rng(6))
    bad = dataclasses.replace(model, threshold=np.zeros_like(model.threshold))
    with pytest.raises(ModelFileError, match="threshold"):
        write_onnx(bad, tmp_path / "bad.onnx")
    spill = dataclasses.replace(model, config=model.config.replace(**{"network.state_isolation": False}))
    with pytest.raises(InvalidValueError, match="state isolation"):
        build_onnx(spill)
    assert list(tmp_path.iterdir()) == []


def test_reader_rejects_missing_truncated_and_foreign_files(tmp_path):
    with pytest.raises(ModelFileError, match="no such"):
        read_onnx(tmp_path / "absent.onnx")
    path = write_onnx(make_model(np.random.default_rng(7)), tmp_path / "m.onnx")
    truncated = tmp_path / "truncated.onnx"
    truncated.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(ModelFileError, match="truncated.onnx"):
        run_onnx(truncated, random_spikes(0, 1, 5, 16))
    foreign = onnx.helper.make_model(
        onnx.helper.make_graph(
            [onnx.helper.make_node("Identity", ["x"], ["y"])],
            "g",
            [onnx.helper.make_tensor_value_info("x", onnx.TensorProto.FLOAT, [1])],
            [onnx.helper.make_tensor_value_info("y", onnx.TensorProto.FLOAT, [1])],
        ),
        ir_version=10,
        opset_imports=[onnx.helper.make_opsetid("", 21)],
    )
    onnx.save(foreign, str(tmp_path / "foreign.onnx"))
    with pytest.raises(ModelFileError, match="not an ONNX graph written by vprsnn-export"):
        read_onnx(tmp_path / "foreign.onnx")


def small_checkpoint(model: FixedPointModel) -> Checkpoint:
    rng = np.random.default_rng(8)
    return Checkpoint(
        config=model.config,
        weights=(rng.random(model.weight_mantissa.shape) * 0.2).astype(np.float32),
        thresholds=(rng.random(model.n_neurons) + 1.0).astype(np.float32),
        calibration=model.calibration,
        reference_place_ids=model.reference_place_ids,
        reference_traversals=["summer"],
        data={"source": "synthetic"},
    )


def test_export_command_writes_checks_and_states_consumers(tmp_path, capsys):
    model = make_model(np.random.default_rng(9), n_inputs=64, n_neurons=10, bits=4)
    save_fixed_point(tmp_path / "fp.npz", model)
    code = main(
        [
            "export",
            str(tmp_path / "fp.npz"),
            "--to",
            "nir,loihi,onnx",
            "--out",
            str(tmp_path / "out"),
            "--check",
            "--check-samples",
            "4",
            "--quiet",
            "--json",
        ]
    )
    assert code == 0
    manifest = json.loads((tmp_path / "out" / "export.json").read_text())
    assert set(manifest["files"]) == {"nir", "loihi", "onnx"} and set(manifest["consumers"]) == {"nir", "loihi", "onnx"}
    results = {r["check"]: r["result"] for r in manifest["checks"]["rows"]}
    assert "FAILED" not in results.values() and list(results.values()).count("ok") >= 5
    assert (tmp_path / "out" / "model.onnx").is_file() and (tmp_path / "out" / "loihi" / "network.json").is_file()


def test_export_command_float_checkpoint_needs_quantisation_for_integer_targets(tmp_path, capsys):
    model = make_model(np.random.default_rng(10), n_inputs=64, n_neurons=10)
    save_checkpoint(tmp_path / "ck.npz", small_checkpoint(model))
    assert main(["export", str(tmp_path / "ck.npz"), "--out", str(tmp_path / "a"), "--quiet"]) == 2
    assert "quantize" in capsys.readouterr().err
    assert main(["export", str(tmp_path / "ck.npz"), "--to", "nir", "--out", str(tmp_path / "b"), "--quiet"]) == 0
    assert (
        main(
            [
                "export",
                str(tmp_path / "ck.npz"),
                "--quantize",
                "8",
                "--to",
                "onnx",
                "--out",
                str(tmp_path / "c"),
                "--check",
                "--check-samples",
                "3",
                "--quiet",
            ]
        )
        == 0
    )
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    assert main(["export", str(tmp_path / "junk.npz"), "--out", str(tmp_path / "d"), "--quiet"]) == 2
    assert "junk.npz" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.skipif(not NORDLAND.is_dir(), reason="the Nordland data folder is absent")
def test_real_nordland_onnx_identical_at_8_4_2_bits(tmp_path):
    """A short training on the real subset, quantised at 8, 4 and 2 bits: ONNX == integer simulator on every query."""
    from vprsnn_export.data.dataset import load_dataset
    from vprsnn_export.data.encoding import query_spikes
    from vprsnn_export.export.quantize import quantize_checkpoint
    from vprsnn_export.trainer.pipeline import train_and_calibrate

    cfg = preset("paper").replace(**{"train.epochs": 3, "seed": 1})
    dataset = load_dataset(
        NORDLAND / "places.csv", ["summer", "winter"], cfg.preprocess, subset=NORDLAND / "subset_100_places.csv"
    )
    ckpt = train_and_calibrate(
        dataset,
        ["summer"],
        cfg,
        device=torch.device("cpu"),
        progress=False,
        selection={"subset": str(NORDLAND / "subset_100_places.csv"), "places": None},
    )
    spikes = query_spikes(dataset.traversal("winter"), dataset.place_ids, "winter", cfg)
    for bits in (8, 4, 2):
        model = quantize_checkpoint(ckpt, "0" * 64, bits, QuantiseOptions())
        path = write_onnx(model, tmp_path / f"m{bits}.onnx")
        expected = simulate(model, spikes)
        out = run_onnx_outputs(path, spikes)
        assert np.array_equal(out.counts, expected.counts.numpy()), bits
        assert int(out.saturations.sum()) == expected.saturations


def test_reader_refuses_an_edited_graph_without_its_outputs_or_with_foreign_operators(tmp_path):
    """Issue 45: an exported graph whose counts output was removed (a KeyError once), or that gained an operator
    the writer never uses, is a ModelFileError naming the file before onnxruntime runs it."""
    import re

    from vprsnn_export.targets import onnx_target
    from vprsnn_export.targets.onnx_session import WRITER_OPS

    written = set(re.findall(r'\.op\(\s*"([A-Za-z]+)"', Path(onnx_target.__file__).read_text()))
    assert WRITER_OPS == written | {"Scan"}  # the allowlist is the writer's own set of operators
    path = write_onnx(make_model(np.random.default_rng(7)), tmp_path / "m.onnx")
    edited = onnx.load(str(path))
    kept = [o for o in edited.graph.output if o.name != "counts"]
    del edited.graph.output[:]
    edited.graph.output.extend(kept)
    onnx.save(edited, str(tmp_path / "no_counts.onnx"))
    with pytest.raises(ModelFileError, match="no output counts"):
        run_onnx(tmp_path / "no_counts.onnx", random_spikes(0, 1, 5, 16))
    grown = onnx.load(str(path))
    grown.graph.node.append(onnx.helper.make_node("Abs", ["spikes"], ["spikes_abs"]))  # valid, but not the writer's
    onnx.save(grown, str(tmp_path / "grown.onnx"))
    with pytest.raises(ModelFileError, match=r"operators export never writes \(Abs\)"):
        read_onnx(tmp_path / "grown.onnx")
