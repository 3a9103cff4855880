"""Loihi-style description: Lava-convention parameters, round trip, malformed files, and the run in Lava itself."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from vprsnn_export.config import preset
from vprsnn_export.errors import ModelFileError
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.export.quantize import QuantiseOptions
from vprsnn_export.io.fileio import sha256_bytes
from vprsnn_export.targets.intsim import simulate
from vprsnn_export.targets.loihi_description import (
    ARRAYS_NAME,
    HEADER_NAME,
    NETX_NAME,
    WEIGHTS_NAME,
    describe,
    lava_weights,
)
from vprsnn_export.targets.loihi_target import lava_weight_matrix, npz_bytes, read_loihi, read_loihi_model, write_loihi

HERE = Path(__file__).resolve().parent
RUN_LAVA = HERE / "lava_conformance" / "run_lava.py"
NORDLAND = HERE.parents[1].parent / "shared/data/nordland_64x32_summer_winter"


def make_model(rng, *, n_inputs=16, n_neurons=6, bits=8, wta=True, uniform=False, p=0.3, dv=205) -> FixedPointModel:
    """Random mantissas; thresholds 1.5-4 times each neuron's expected current (input rate p), so neurons integrate."""
    side = int(round(n_inputs**0.5))
    cfg = preset("paper").replace(
        **{
            "preprocess.image_size": side,
            "preprocess.patch_size": 1,
            "network.n_inputs": n_inputs,
            "network.n_neurons": n_neurons,
            "network.wta": wta,
            "encoder.timesteps": 30,
        }
    )
    q = rng.integers(0, 2**bits, (n_inputs, n_neurons)).astype(np.int32)
    expected = np.maximum(p * q.sum(axis=0), 1.0)
    threshold = (
        np.full(n_neurons, int(2.5 * expected.mean()))
        if uniform
        else np.round(expected * rng.uniform(1.5, 4, n_neurons))
    )
    return FixedPointModel(
        bits=bits,
        weight_mantissa=q,
        scale_multiplier=rng.integers(1, 2**16, n_neurons).astype(np.int32),
        scale_exponent=-20,
        threshold=np.clip(threshold, 1, 2**17 - 1).astype(np.int32),
        decay_dv=dv,
        config=cfg,
        calibration=rng.integers(0, 4, (n_neurons, 3)).astype(np.int64),
        float_calibration=rng.integers(0, 4, (n_neurons, 3)).astype(np.int64),
        reference_place_ids=np.arange(3, dtype=np.int64),
        reference_traversals=["summer"],
        quantisation={"per_neuron": True},
        source_sha256="0" * 64,
    )


def random_spikes(seed: int, n: int, timesteps: int, n_inputs: int, p: float = 0.3) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return (torch.rand((n, timesteps, n_inputs), generator=generator) < p).to(torch.uint8)


@pytest.mark.parametrize("bits", [2, 4, 8])
def test_lava_weight_encoding_recovers_the_exact_currents(bits):
    rng = np.random.default_rng(bits)
    model = make_model(rng, bits=bits)
    weights, num_weight_bits, weight_exp = lava_weights(model)
    assert weights.shape == (6, 16) and weights.max() <= 255 and weights.min() >= 0
    assert num_weight_bits == bits and weight_exp == -(8 - bits)
    spikes = rng.integers(0, 2, (50, 16))
    # Lava's Dense: truncate to num_weight_bits (no-op: low bits are zero), sum, shift by weight_exp
    truncated = (weights >> (8 - num_weight_bits)) << (8 - num_weight_bits)
    assert np.array_equal(truncated, weights)
    lava_currents = (spikes @ truncated.T) >> -weight_exp
    assert np.array_equal(lava_currents, spikes @ model.weight_mantissa)


def test_header_names_every_lava_parameter():
    model = make_model(np.random.default_rng(1), bits=4)
    desc = describe(model)
    exc = desc.header["populations"][1]
    conn = desc.header["connections"][0]
    assert (exc["du"], exc["dv"], exc["vth_shift"], exc["bias_exp"]) == (4095, 205, 6, 0)
    assert np.array_equal(desc.arrays[exc["vth"]], model.threshold)
    assert conn["sign_mode"] == "EXCITATORY" and conn["num_weight_bits"] == 4 and conn["weight_exp"] == -4
    assert desc.header["wta"]["enabled"] and np.array_equal(desc.arrays["wta_score_multiplier"], model.scale_multiplier)
    assert desc.header["populations"][0]["encoder"]["timesteps"] == 30
    assert not conn["u_wrap_possible"]


@pytest.mark.parametrize("bits", [2, 8])
def test_round_trip_rebuilds_the_model_exactly(tmp_path, bits):
    model = make_model(np.random.default_rng(bits), bits=bits)
    write_loihi(model, tmp_path / "d", source_sha256="ef" * 32)
    rebuilt = read_loihi_model(tmp_path / "d")
    for f in dataclasses.fields(model):
        a, b = getattr(model, f.name), getattr(rebuilt, f.name)
        assert np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b, f.name
    assert read_loihi(tmp_path / "d" / HEADER_NAME).header["source_sha256"] == "ef" * 32
    spikes = random_spikes(bits, 4, 30, 16)
    assert torch.equal(simulate(model, spikes, record=True).raster, simulate(rebuilt, spikes, record=True).raster)


@pytest.mark.parametrize("uniform", [True, False])
def test_netx_file_holds_one_or_per_neuron_thresholds(tmp_path, uniform):
    model = make_model(np.random.default_rng(3), uniform=uniform, bits=4)
    written = write_loihi(model, tmp_path / "b")
    assert read_loihi(tmp_path / "b").header["netx"]["file"] == NETX_NAME
    with h5py.File(written["netx"], "r") as f:
        layer = f["layer/0"]
        assert layer["type"][()] == b"dense" and list(layer["shape"][()]) == [6]
        assert layer["weight"].dtype == np.uint8 and np.array_equal(layer["weight"][()], model.weight_mantissa.T)
        neuron = layer["neuron"]
        assert neuron["type"][()] == b"CUBA" and neuron["iDecay"][()] == 4096 and neuron["vDecay"][()] == 205
        vth = neuron["vThMant"][()]
        if uniform:
            assert np.ndim(vth) == 0 and vth == model.threshold[0]
        else:
            assert vth.shape == (6,) and np.array_equal(vth, model.threshold)


@pytest.mark.parametrize("bits", [2, 3, 4, 5, 6, 7, 8])
def test_weights_are_stored_bit_packed_as_the_header_states(tmp_path, bits):
    model = make_model(np.random.default_rng(bits), n_inputs=25, n_neurons=7, bits=bits)
    write_loihi(model, tmp_path / "d")
    desc = read_loihi(tmp_path / "d")
    conn = desc.header["connections"][0]
    storage = conn["weights_storage"]
    packed = desc.arrays[conn["weights"]]
    assert desc.header["format_version"] == 2 and conn["weights"] == WEIGHTS_NAME
    assert storage["packing"] == "lsb-first-bitstream" and storage["shape"] == [7, 25] and storage["bits"] == bits
    assert packed.dtype == np.uint8 and packed.shape == ((7 * 25 * bits + 7) // 8,) == (storage["bytes"],)
    # the documented rule, spelled out: value k = sum_i bit(k bits + i) 2**i, bit n = bit n % 8 of byte n // 8
    stream = [(int(packed[n // 8]) >> (n % 8)) & 1 for n in range(7 * 25 * bits)]
    values = [sum(stream[k * bits + i] << i for i in range(bits)) for k in range(7 * 25)]
    assert np.array_equal(np.array(values).reshape(7, 25), model.weight_mantissa.T)
    assert np.array_equal(lava_weight_matrix(desc), lava_weights(model)[0])


def rewrite(folder: Path, header: dict, arrays: dict[str, np.ndarray]) -> None:
    """Replace a description's arrays and header (the header naming the new arrays' sha256)."""
    blob = npz_bytes(arrays)
    header["arrays"]["sha256"] = sha256_bytes(blob)
    (folder / ARRAYS_NAME).write_bytes(blob)
    (folder / HEADER_NAME).write_text(json.dumps(header))


def test_version_1_descriptions_still_load_and_unknown_versions_fail_clearly(tmp_path):
    model = make_model(np.random.default_rng(11), bits=4)
    write_loihi(model, tmp_path / "d")
    desc = read_loihi(tmp_path / "d")
    old = {name: value for name, value in desc.arrays.items() if name != WEIGHTS_NAME}
    old["input_exc_weights"] = lava_weights(model)[0]
    header = json.loads(json.dumps(desc.header))
    header["format_version"] = 1
    header["connections"][0]["weights"] = "input_exc_weights"
    del header["connections"][0]["weights_storage"]
    rewrite(tmp_path / "d", header, old)
    assert np.array_equal(read_loihi_model(tmp_path / "d").weight_mantissa, model.weight_mantissa)
    header["format_version"] = 3
    rewrite(tmp_path / "d", header, old)
    with pytest.raises(ModelFileError, match="unsupported Loihi description version 3"):
        read_loihi(tmp_path / "d")


def test_reader_rejects_packed_weights_that_do_not_match_the_header(tmp_path):
    write_loihi(make_model(np.random.default_rng(12), bits=3), tmp_path / "d")
    desc = read_loihi(tmp_path / "d")
    short = dict(desc.arrays, **{WEIGHTS_NAME: desc.arrays[WEIGHTS_NAME][:-1]})
    rewrite(tmp_path / "d", json.loads(json.dumps(desc.header)), short)
    with pytest.raises(ModelFileError, match="weights cannot be read.*packed uint8 bytes"):
        read_loihi(tmp_path / "d")
    header = json.loads(json.dumps(desc.header))
    header["connections"][0]["weights_storage"]["bits"] = 4
    rewrite(tmp_path / "d", header, desc.arrays)
    with pytest.raises(ModelFileError, match="num_weight_bits"):
        read_loihi_model(tmp_path / "d")


def test_reader_rejects_missing_corrupt_and_mismatched_files(tmp_path):
    with pytest.raises(ModelFileError, match="network.json missing"):
        read_loihi(tmp_path)
    write_loihi(make_model(np.random.default_rng(4)), tmp_path / "d")
    header = tmp_path / "d" / HEADER_NAME
    arrays = tmp_path / "d" / ARRAYS_NAME
    good_header, good_arrays = header.read_bytes(), arrays.read_bytes()
    header.write_bytes(good_header[: len(good_header) // 2])
    with pytest.raises(ModelFileError, match="not valid JSON"):
        read_loihi(tmp_path / "d")
    header.write_bytes(good_header)
    arrays.write_bytes(good_arrays[:100])
    with pytest.raises(ModelFileError, match="sha256"):
        read_loihi(tmp_path / "d")
    arrays.unlink()
    with pytest.raises(ModelFileError, match="missing"):
        read_loihi(tmp_path / "d")
    arrays.write_bytes(good_arrays)
    meta = json.loads(good_header)
    meta["format"] = "something-else"
    header.write_text(json.dumps(meta))
    with pytest.raises(ModelFileError, match="not a vprsnn Loihi description"):
        read_loihi(tmp_path / "d")


def test_writer_validates_before_writing(tmp_path):
    model = make_model(np.random.default_rng(5))
    bad = dataclasses.replace(model, threshold=np.full(6, 2**17, dtype=np.int32))
    with pytest.raises(ModelFileError, match="threshold"):
        write_loihi(bad, tmp_path / "d")
    assert not (tmp_path / "d").exists()


# --- the conformance run in Lava (lava-nc 0.10, Python 3.10) --------------------------------------------


def run_in_lava(python: Path, folder: Path, spikes: torch.Tensor, tmp_path: Path, *, wta: bool = False) -> torch.Tensor:
    """Lava's raster (N, T, neurons); with ``wta`` the WtaReadout's raster, the LIF's candidates in candidates.npy."""
    np.save(tmp_path / "spikes.npy", spikes.numpy())
    mode = ["--wta"] if wta else []
    extra = [str(tmp_path / "candidates.npy")] if wta else []
    done = subprocess.run(
        [str(python), str(RUN_LAVA), *mode, str(folder), str(tmp_path / "spikes.npy"), str(tmp_path / "raster.npy")]
        + extra,
        capture_output=True,
        text=True,
        timeout=1800,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return torch.from_numpy(np.load(tmp_path / "raster.npy").astype(bool))


def wta_select(candidates: torch.Tensor, spikes: torch.Tensor, model: FixedPointModel) -> torch.Tensor:
    """What a Lava user adds for hard WTA: of each step's candidates in each module (group of n neurons) keep the
    largest a_j m_j (lowest index on ties)."""
    currents = spikes.to(torch.int64) @ torch.as_tensor(model.weight_mantissa, dtype=torch.int64)
    score = torch.where(candidates, currents * torch.as_tensor(model.scale_multiplier, dtype=torch.int64), -1)
    n, timesteps, neurons = candidates.shape
    group = model.config.network.n_neurons
    grouped, chosen = score.reshape(n, timesteps, -1, group), candidates.reshape(n, timesteps, -1, group)
    winner = grouped.argmax(dim=3, keepdim=True)
    return torch.zeros_like(chosen).scatter_(3, winner, chosen.any(dim=3, keepdim=True)).reshape(candidates.shape)


def with_wta(model: FixedPointModel, wta: bool) -> FixedPointModel:
    """``model`` with the WTA switched on or off."""
    return dataclasses.replace(model, config=model.config.replace(**{"network.wta": wta}))


def assert_lava_conforms(model: FixedPointModel, spikes: torch.Tensor, tmp_path: Path, python: Path) -> int:
    write_loihi(model, tmp_path / "desc")
    lava = run_in_lava(python, tmp_path / "desc", spikes, tmp_path)
    expected = simulate(with_wta(model, False), spikes, record=True).raster
    assert torch.equal(lava, expected), f"{int((lava != expected).sum())} of {lava.numel()} spikes differ"
    assert torch.equal(wta_select(lava, spikes, model), simulate(with_wta(model, True), spikes, record=True).raster)
    return int(lava.sum())


def wta_steps(candidates: torch.Tensor, spikes: torch.Tensor, model: FixedPointModel) -> tuple[int, int]:
    """(steps with two or more candidates, steps whose largest candidate score a_j m_j is shared: the tie rule decides)."""
    currents = spikes.to(torch.int64) @ torch.as_tensor(model.weight_mantissa, dtype=torch.int64)
    score = torch.where(candidates, currents * torch.as_tensor(model.scale_multiplier, dtype=torch.int64), -1)
    top = score.max(dim=2, keepdim=True).values
    contested = candidates.sum(dim=2) > 1
    tied = ((score == top) & candidates).sum(dim=2) > 1
    return int(contested.sum()), int(tied.sum())


def assert_lava_wta_conforms(model: FixedPointModel, spikes: torch.Tensor, tmp_path: Path, python: Path) -> int:
    """The network with Lava's WtaReadout process: its raster is the simulator's WTA-on raster, the LIF's the WTA-off."""
    write_loihi(model, tmp_path / "desc")
    winners = run_in_lava(python, tmp_path / "desc", spikes, tmp_path, wta=True)
    candidates = torch.from_numpy(np.load(tmp_path / "candidates.npy").astype(bool))
    expected_off = simulate(with_wta(model, False), spikes, record=True).raster
    expected_on = simulate(with_wta(model, True), spikes, record=True).raster
    assert torch.equal(candidates, expected_off), f"{int((candidates != expected_off).sum())} candidate spikes differ"
    assert torch.equal(winners, expected_on), (
        f"{int((winners != expected_on).sum())} of {winners.numel()} spikes differ"
    )
    assert int(winners.sum(dim=2).max()) <= 1
    return int(winners.sum())


@pytest.mark.slow
@pytest.mark.parametrize("bits", [8, 4, 2])
def test_lava_runs_the_description_spike_for_spike(tmp_path, bits, lava_python):
    """Full size (784 x 400), per-neuron thresholds, WTA off in Lava, against the integer simulator."""
    python = lava_python
    model = make_model(np.random.default_rng(bits), n_inputs=784, n_neurons=400, bits=bits, p=0.12)
    spikes = random_spikes(bits, 3, 60, 784, p=0.12)
    assert assert_lava_conforms(model, spikes, tmp_path, python) > 0


@pytest.fixture(scope="module")
def real_case() -> tuple[FixedPointModel, torch.Tensor]:
    """The real model and queries of the real-data tests, built once (training takes a while)."""
    if not NORDLAND.is_dir():
        pytest.skip("the Nordland data folder is absent")
    return real_model_and_queries(int(os.environ.get("VPRSNN_LAVA_QUERIES", "4")))


def real_model_and_queries(n: int) -> tuple[FixedPointModel, torch.Tensor]:
    """VPRSNN_LAVA_MODEL (a fixed-point model file) when set, else a 3-epoch network quantised at 8 bits per neuron;
    with the spike trains of its first ``n`` winter queries."""
    from vprsnn_export.data.dataset import load_dataset
    from vprsnn_export.data.encoding import query_spikes
    from vprsnn_export.export.model import load_fixed_point
    from vprsnn_export.export.quantize import quantize_checkpoint
    from vprsnn_export.trainer.pipeline import train_and_calibrate

    given = os.environ.get("VPRSNN_LAVA_MODEL")
    model = load_fixed_point(given) if given else None
    cfg = model.config if model else preset("paper").replace(**{"train.epochs": 3, "seed": 1})
    subset = NORDLAND / "subset_100_places.csv"
    dataset = load_dataset(NORDLAND / "places.csv", ["summer", "winter"], cfg.preprocess, subset=subset)
    if model is None:
        ckpt = train_and_calibrate(
            dataset,
            ["summer"],
            cfg,
            device=torch.device("cpu"),
            progress=False,
            selection={"subset": str(subset), "places": None},
        )
        model = quantize_checkpoint(ckpt, "0" * 64, 8, QuantiseOptions())
    return model, query_spikes(dataset.traversal("winter")[:n], dataset.place_ids[:n], "winter", cfg)


@pytest.mark.slow
@pytest.mark.skipif(not NORDLAND.is_dir(), reason="the Nordland data folder is absent")
def test_lava_on_real_nordland_queries(tmp_path, lava_python, real_case):
    """Real winter queries at the model's T through Lava (WTA off) against the integer simulator.

    VPRSNN_LAVA_MODEL=path runs a given fixed-point model, VPRSNN_LAVA_QUERIES=n sets the number of queries (4).
    """
    model, spikes = real_case
    assert assert_lava_conforms(model, spikes, tmp_path, lava_python) > 0


@pytest.mark.slow
@pytest.mark.parametrize("bits", [8, 4, 2])
def test_lava_wta_readout_emits_the_wta_on_raster(tmp_path, bits, lava_python):
    """Full size (784 x 400): Dense + LIF + the WtaReadout process in Lava, spike for spike with WTA on."""
    model = make_model(np.random.default_rng(bits), n_inputs=784, n_neurons=400, bits=bits, p=0.12)
    spikes = random_spikes(bits, 3, 60, 784, p=0.12)
    assert assert_lava_wta_conforms(model, spikes, tmp_path, lava_python) > 0
    contested, _ = wta_steps(simulate(with_wta(model, False), spikes, record=True).raster, spikes, model)
    assert contested > 0


@pytest.mark.slow
def test_lava_wta_readout_breaks_ties_to_the_lowest_index(tmp_path, lava_python):
    """Equal multipliers and 2-bit weights make equal scores common: the readout keeps the lowest index."""
    rng = np.random.default_rng(21)
    model = make_model(rng, n_inputs=64, n_neurons=40, bits=2, p=0.3, uniform=True)
    model = dataclasses.replace(model, scale_multiplier=np.full(40, 7, dtype=np.int32))
    spikes = random_spikes(21, 4, 30, 64, p=0.3)
    assert assert_lava_wta_conforms(model, spikes, tmp_path, lava_python) > 0
    _, tied = wta_steps(simulate(with_wta(model, False), spikes, record=True).raster, spikes, model)
    assert tied > 0


@pytest.mark.slow
@pytest.mark.skipif(not NORDLAND.is_dir(), reason="the Nordland data folder is absent")
def test_lava_wta_readout_on_real_nordland_queries(tmp_path, lava_python, real_case):
    """Real winter queries through Dense + LIF + WtaReadout in Lava against the integer simulator with WTA on."""
    model, spikes = real_case
    assert assert_lava_wta_conforms(model, spikes, tmp_path, lava_python) > 0
