"""An exported file decides alone: read with only onnxruntime (or nir) and numpy, its metadata's encoder contract,
input layout, reference place ids and decision rule give the project's decisions on every query.

The deciding code (``outsider_*``) imports nothing of vprsnn_export: it reads the file's metadata, encodes the
preprocessed query images by the stated generator and seed rule, runs the graph (or the NIR integer semantics) and
applies the stated readout. The project's decisions come from its own pipeline (query_spikes, the integer simulator,
the Readout) on a network trained here on a synthetic route no other test uses (31 places, route seed 11, place
ids from 700).
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

import nir
import numpy as np
import onnxruntime as ort
import pytest

# ---- the outsider: numpy, onnxruntime, nir and the standard library only ---------------------------------------------


def outsider_spikes(contract: dict, pixels: np.ndarray, place_ids: np.ndarray, traversal: str) -> np.ndarray:
    """Spikes (N, T, inputs) uint8 of preprocessed images (N, inputs) by the file's encoder contract."""
    steps, inputs = contract["timesteps"], contract["preprocess"]["inputs"]
    template = re.search(r"key = '([^']*)'", contract["generator_seed"]).group(1)
    pixels = pixels.astype(np.float32)
    if "input_gain" in contract:  # a network adapted to a second traversal: x -> g x / max(g x) first
        gained = pixels * np.asarray(contract["input_gain"], dtype=np.float32)
        top = gained.max(axis=1, keepdims=True)
        pixels = np.divide(gained, top, out=np.zeros_like(gained), where=top > 0)
    p = np.clip(np.float32(contract["rate_scale"]) * pixels, np.float32(0), np.float32(1))
    limits = np.ceil(p.astype(np.float64) * 2.0**24)
    out = np.empty((len(place_ids), steps, inputs), dtype=np.uint8)
    for n, place_id in enumerate(place_ids):  # one generator per presentation, as the contract states
        key = template.replace("<traversal>", traversal).replace("<place_id>", str(int(place_id)))
        g = int.from_bytes(hashlib.sha256(key.encode("utf-8")).digest()[:8], "little") & (2**63 - 1)
        words = np.random.RandomState(g % 2**32).randint(0, 2**32, size=steps * inputs, dtype=np.uint32)
        out[n] = (words & 0xFFFFFF).reshape(steps, inputs) < limits[n]
    return out


def outsider_decide(distribution: np.ndarray, place_ids: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """(place id or -1, confidence) per row by the decision rule: argmax (first on ties), none when flat."""
    flat = distribution.max(axis=1) == distribution.min(axis=1)
    places = np.asarray(place_ids, dtype=np.int64)[distribution.argmax(axis=1)]
    return np.where(flat, -1, places), np.where(flat, 0.0, distribution.max(axis=1))


def outsider_onnx(path: str, pixels: np.ndarray, query_ids: np.ndarray, traversal: str):
    """Decisions from the ONNX file alone."""
    sess = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    props = sess.get_modelmeta().custom_metadata_map
    spikes = outsider_spikes(json.loads(props["vprsnn.encoder_contract"]), pixels, query_ids, traversal)
    (wprob,) = sess.run(["wprob"], {"spikes": spikes.transpose(1, 0, 2)})  # time first: vprsnn.input_layout
    return outsider_decide(wprob, json.loads(props["vprsnn.reference_place_ids"]))


def outsider_wprob(calibration: np.ndarray, counts: np.ndarray, gamma: float) -> np.ndarray:
    """The W+Prob distribution by the NIR metadata's wprob_rule (a single network)."""
    s = calibration.astype(np.float64)
    c = counts.astype(np.float64)
    omega = (s > 0).sum(axis=1, keepdims=True).astype(np.float64)
    s1 = s / np.where(omega > gamma * s.shape[1], omega, 1.0)
    rowsum = s.sum(axis=1, keepdims=True)
    s2 = s1 * (s / np.where(rowsum > 0, rowsum, 1.0))
    colsum = s.sum(axis=0, keepdims=True)
    inverse = np.where(colsum > 0, 1.0 / np.where(colsum > 0, colsum, 1.0), 0.0)
    score = (c @ s2) * (((c > 0).astype(np.float64) @ s) * inverse)
    lo, hi = score.min(axis=1, keepdims=True), score.max(axis=1, keepdims=True)
    span = hi - lo
    norm = (score - lo) / np.where(span > 0, span, 1.0)
    total = norm.sum(axis=1, keepdims=True)
    return np.where(span > 0, norm / np.where(total > 0, total, 1.0), 1.0 / s.shape[1])


def outsider_nir(path: str, pixels: np.ndarray, query_ids: np.ndarray, traversal: str):
    """Decisions from the NIR file alone: its integer semantics and hard-WTA rule run in numpy."""
    graph = nir.read(path)
    meta = graph.metadata
    semantics = json.loads(meta["integer_semantics"])
    rule = json.loads(meta["readout_rule"])
    spikes = outsider_spikes(json.loads(meta["encoder_contract"]), pixels, query_ids, traversal)
    q = np.asarray(graph.nodes["linear"].weight).astype(np.int64)  # (neurons, inputs)
    shift = semantics["voltage_shift"]
    vth = np.asarray(graph.nodes["lif"].v_threshold).astype(np.int64) << shift
    multiplier = np.asarray(meta["wta_score_multiplier"]).astype(np.int64)
    keep, divisor = semantics["decay"]["multiplier"], semantics["decay"]["divisor"]
    low, high = semantics["saturation"]["min"], semantics["saturation"]["max"]
    n_queries, neurons = spikes.shape[0], q.shape[0]
    group = rule["group_size"]
    v = np.zeros((n_queries, neurons), dtype=np.int64)
    counts = np.zeros_like(v)
    for t in range(spikes.shape[1]):
        a = spikes[:, t].astype(np.int64) @ q.T
        decayed = v * keep
        v = np.clip(np.sign(decayed) * (np.abs(decayed) // divisor) + (a << shift), low, high)
        candidates = v > vth
        masked = np.where(candidates, a * multiplier, -1).reshape(n_queries, -1, group)
        winner = masked.argmax(axis=2)[:, :, None] == np.arange(group)
        counts += (winner.reshape(n_queries, neurons) & candidates).astype(np.int64)
        v = np.where(candidates, 0, v)
    gamma = json.loads(meta["header_json"])["config"]["assignment"]["gamma"]
    wprob = outsider_wprob(np.asarray(meta["calibration"]), counts, gamma)
    return outsider_decide(wprob, list(np.asarray(meta["reference_place_ids"]).tolist()))


# ---- the project's decisions and the checks ---------------------------------------------------------------------------

ROUTE_PLACES, ROUTE_SEED, FIRST_ID, QUERY = 31, 11, 700, "winter"


def train_unseen(**overrides):
    """A network (Config defaults, 40 steps, 2 epochs, 16 neurons, ``overrides``) trained on a route no other test
    uses, and its data set."""
    from vprsnn_export.config import Config
    from vprsnn_export.data.dataset import Dataset
    from vprsnn_export.data.synthetic import synthetic_route
    from vprsnn_export.trainer.pipeline import train_and_calibrate

    settings = {"encoder.timesteps": 40, "train.epochs": 2, "network.n_neurons": 16, "seed": 5, **overrides}
    cfg = Config().replace(**settings)
    route = synthetic_route(ROUTE_PLACES, ("summer", QUERY), seed=ROUTE_SEED)
    ids = np.arange(FIRST_ID, FIRST_ID + ROUTE_PLACES)
    data = Dataset.from_arrays(route, cfg.preprocess, place_ids=ids, source="synthetic-unseen")
    ckpt = train_and_calibrate(data, ["summer"], cfg, progress=False, selection={"subset": None, "places": None})
    return ckpt, data


@pytest.fixture(scope="module")
def unseen_route():
    return train_unseen()


def project_decisions(model, data) -> tuple[np.ndarray, np.ndarray]:
    from vprsnn_export.data.encoding import query_spikes
    from vprsnn_export.readout.metrics import predicted_place_ids
    from vprsnn_export.readout.scoring import Readout
    from vprsnn_export.readout.strategies import decide
    from vprsnn_export.targets.intsim import simulate

    spikes = query_spikes(data.traversal(QUERY), data.place_ids, QUERY, model.config)
    counts = simulate(model, spikes).counts.numpy()
    pred, confidence = decide(Readout.of(model.calibration, model.config).scores(counts)["wprob"], "wprob")
    return predicted_place_ids(pred, model.reference_place_ids).filled(-1), confidence


@pytest.fixture(scope="module", params=[8, 2])
def exported(request, unseen_route, tmp_path_factory):
    from vprsnn_export.export.quantize import QuantiseOptions, quantize_checkpoint
    from vprsnn_export.targets.nir_target import write_nir
    from vprsnn_export.targets.onnx_target import write_onnx

    ckpt, data = unseen_route
    model = quantize_checkpoint(ckpt, "0" * 64, request.param, QuantiseOptions())
    folder = tmp_path_factory.mktemp(f"standalone{request.param}")
    return model, data, write_onnx(model, folder / "model.onnx"), write_nir(model, folder / "model.nir")


def test_the_onnx_file_alone_makes_the_projects_decisions(exported):
    model, data, onnx_path, _ = exported
    places, confidence = outsider_onnx(str(onnx_path), data.traversal(QUERY), data.place_ids, QUERY)
    expected_places, expected_confidence = project_decisions(model, data)
    assert len(places) == ROUTE_PLACES and (places >= FIRST_ID).sum() > ROUTE_PLACES // 2  # ids, not indices
    assert np.array_equal(places, expected_places)  # 100 % of queries
    np.testing.assert_allclose(confidence, expected_confidence, rtol=1e-12, atol=1e-15)


def test_an_ensembles_onnx_file_alone_makes_the_projects_decisions(tmp_path):
    """Three modules (11, 11 and 9 places): the graph's head carries the region readout, the outsider code is the same."""
    from vprsnn_export.export.quantize import QuantiseOptions, quantize_checkpoint
    from vprsnn_export.targets.onnx_target import write_onnx

    ckpt, data = train_unseen(**{"train.module_size": 11})
    model = quantize_checkpoint(ckpt, "0" * 64, 4, QuantiseOptions())
    assert model.n_neurons == 3 * 16
    places, confidence = outsider_onnx(
        str(write_onnx(model, tmp_path / "m.onnx")), data.traversal(QUERY), data.place_ids, QUERY
    )
    expected_places, expected_confidence = project_decisions(model, data)
    assert (places >= FIRST_ID).sum() > ROUTE_PLACES // 2 and np.array_equal(places, expected_places)
    np.testing.assert_allclose(confidence, expected_confidence, rtol=1e-12, atol=1e-15)


def test_an_adapted_networks_files_alone_make_the_projects_decisions(tmp_path):
    """A network with a per-input gain learnt from the query traversal's frames (train --adapt-from): the gain is
    in both files' encoder contract, and the outsider applies it as the contract says."""
    from vprsnn_export.export.quantize import QuantiseOptions, quantize_checkpoint
    from vprsnn_export.targets.nir_target import write_nir
    from vprsnn_export.targets.onnx_target import write_onnx

    rng = np.random.default_rng(3)
    ckpt, data = train_unseen(**{"encoder.input_gain": rng.uniform(0.2, 2.0, 1568).tolist()})
    model = quantize_checkpoint(ckpt, "0" * 64, 8, QuantiseOptions())
    expected_places, expected_confidence = project_decisions(model, data)
    for outsider, path in (
        (outsider_onnx, write_onnx(model, tmp_path / "m.onnx")),
        (outsider_nir, write_nir(model, tmp_path / "m.nir")),
    ):
        places, confidence = outsider(str(path), data.traversal(QUERY), data.place_ids, QUERY)
        assert np.array_equal(places, expected_places)
        np.testing.assert_allclose(confidence, expected_confidence, rtol=1e-12, atol=1e-15)
    plain, _ = train_unseen()  # the gain changes the spikes, so a file without it would not decide alike
    assert not np.array_equal(plain.weights, ckpt.weights)


def test_the_nir_file_alone_makes_the_projects_decisions(exported):
    model, data, _, nir_path = exported
    places, confidence = outsider_nir(str(nir_path), data.traversal(QUERY), data.place_ids, QUERY)
    expected_places, expected_confidence = project_decisions(model, data)
    assert np.array_equal(places, expected_places)
    np.testing.assert_allclose(confidence, expected_confidence, rtol=1e-12, atol=1e-15)


def test_the_contract_reproduces_the_projects_query_spikes(exported):
    from vprsnn_export.data.encoding import query_spikes

    model, data, onnx_path, nir_path = exported
    props = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"]).get_modelmeta()
    contract = json.loads(props.custom_metadata_map["vprsnn.encoder_contract"])
    assert contract == json.loads(nir.read(str(nir_path)).metadata["encoder_contract"])
    ours = outsider_spikes(contract, data.traversal(QUERY), data.place_ids, QUERY)
    assert np.array_equal(ours, query_spikes(data.traversal(QUERY), data.place_ids, QUERY, model.config).numpy())
    assert contract["preprocess"]["inputs"] == model.n_inputs == 1568  # DoG ON/OFF: 2 x 28 x 28


def test_a_wrong_layout_or_width_is_refused_by_onnxruntime(exported):
    model, data, onnx_path, _ = exported
    sess = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    steps, inputs = model.config.encoder.timesteps, model.n_inputs
    assert sess.get_inputs()[0].shape == [steps, "batch", inputs]
    spikes = np.zeros((ROUTE_PLACES, steps, inputs), dtype=np.uint8)
    sess.run(["counts"], {"spikes": spikes.transpose(1, 0, 2)})  # (T, N, inputs): accepted
    for wrong in (spikes, spikes[:, :, : inputs // 2].transpose(1, 0, 2)):  # (N, T, inputs); half the width
        with pytest.raises(Exception, match="[Ii]nvalid dimensions"):
            sess.run(["counts"], {"spikes": wrong})


def test_the_projects_runner_refuses_another_time_length_or_width_in_one_line(exported):
    from vprsnn_export.errors import InvalidValueError
    from vprsnn_export.targets.onnx_session import run_onnx

    model, _, onnx_path, _ = exported
    steps, inputs = model.config.encoder.timesteps, model.n_inputs
    assert run_onnx(onnx_path, np.zeros((2, steps, inputs), dtype=np.uint8)).shape == (2, model.n_neurons)
    for shape in ((2, steps + 1, inputs), (2, steps, inputs - 1), (steps, 2, inputs)):
        with pytest.raises(InvalidValueError, match=rf"\(N, {steps}, {inputs}\) for this graph"):
            run_onnx(onnx_path, np.zeros(shape, dtype=np.uint8))


def test_the_added_metadata_keeps_the_file_deterministic(exported, tmp_path):
    from vprsnn_export.targets.onnx_target import write_onnx

    model, _, onnx_path, _ = exported
    assert write_onnx(model, tmp_path / "again.onnx").read_bytes() == onnx_path.read_bytes()
    props = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"]).get_modelmeta()
    assert json.loads(props.custom_metadata_map["vprsnn.reference_place_ids"]) == model.reference_place_ids.tolist()


NORDLAND = Path(__file__).resolve().parents[2].parent / "shared/data/nordland_64x32_summer_winter"


@pytest.mark.slow
@pytest.mark.skipif(not NORDLAND.is_dir(), reason="the Nordland data folder is absent")
def test_real_subset_files_alone_make_the_projects_decisions(tmp_path):
    """The default network (3 epochs to bound the test) on the real 100-place subset: ONNX and NIR files decide alone."""
    from vprsnn_export.config import Config
    from vprsnn_export.data.dataset import load_dataset
    from vprsnn_export.export.quantize import QuantiseOptions, quantize_checkpoint
    from vprsnn_export.targets.nir_target import write_nir
    from vprsnn_export.targets.onnx_target import write_onnx
    from vprsnn_export.trainer.pipeline import train_and_calibrate

    cfg = Config().replace(**{"train.epochs": 3, "seed": 1})
    subset = NORDLAND / "subset_100_places.csv"
    data = load_dataset(NORDLAND / "places.csv", ["summer", QUERY], cfg.preprocess, subset=subset)
    ckpt = train_and_calibrate(data, ["summer"], cfg, progress=False, selection={"subset": str(subset), "places": None})
    for bits in (8, 2):
        model = quantize_checkpoint(ckpt, "0" * 64, bits, QuantiseOptions())
        expected, _ = project_decisions(model, data)
        for outsider, path in (
            (outsider_onnx, write_onnx(model, tmp_path / f"m{bits}.onnx")),
            (outsider_nir, write_nir(model, tmp_path / f"m{bits}.nir")),
        ):
            places, _ = outsider(str(path), data.traversal(QUERY), data.place_ids, QUERY)
            assert np.array_equal(places, expected), (bits, path.name)


def test_the_loihi_header_states_the_same_contract_place_ids_and_width(exported, tmp_path):
    from vprsnn_export.targets.loihi_target import write_loihi

    model, _, onnx_path, _ = exported
    write_loihi(model, tmp_path / "loihi")
    header = json.loads((tmp_path / "loihi" / "network.json").read_text())
    props = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"]).get_modelmeta()
    source = header["populations"][0]
    assert source["encoder"]["contract"] == json.loads(props.custom_metadata_map["vprsnn.encoder_contract"])
    assert header["readout"]["place_ids"] == model.reference_place_ids.tolist()
    assert f"spikes ({model.n_inputs}, steps)" in source["lava"] and source["size"] == model.n_inputs
    assert header["readout"]["decision"]["place"].startswith("reference_place_ids[argmax")
