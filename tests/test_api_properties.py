"""Property tests of the public API: any argument either works or is refused with the project's error.

Each public function is called with one argument replaced by a value drawn from wrong types,
wrong shapes, NaN/inf, empty and huge values; the call must return or raise a VprError (never an
AttributeError, a numpy/torch error or a bare ValueError). Then the specific promises: NaN/inf
pixels are refused everywhere, a calibration must match its reference ids, regions must tile the
places, and every file written by a save_* function loads back equal (or is refused before writing).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import array_shapes, arrays

import vprsnn_export as vx
from vprsnn_export.arguments import ascii_int, ascii_uint
from vprsnn_export.errors import VprError
from vprsnn_export.io.fileio import JSON_MAX_DEPTH, JSON_MAX_DIGITS, parse_json

FAST = settings(max_examples=6, deadline=None, suppress_health_check=list(HealthCheck), database=None)

BAD = st.one_of(
    st.none(),
    st.booleans(),
    st.text(max_size=4),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(2**80), max_value=2**80),
    st.lists(st.integers(min_value=-3, max_value=3), max_size=3),
    st.builds(object),
    arrays(
        st.sampled_from([np.float64, np.int64, np.uint8, np.bool_]),
        array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=3),
    ),
)


class Fixtures:
    """A tiny trained network, its 4-bit model and the data, built once for the module."""

    def __init__(self, folder: Path) -> None:
        vx.set_threads(1)
        cfg = vx.Config().replace(**{"encoder.timesteps": 8, "train.epochs": 1, "network.n_neurons": 4})
        self.cfg = cfg
        self.data = vx.load_dataset("synthetic:5", ["summer", "winter"], cfg.preprocess)
        self.ckpt = vx.train_and_calibrate(self.data, ["summer"], cfg, progress=False)
        self.winter = self.data.traversal("winter")
        self.places = self.data.place_ids
        self.reference = {"summer": self.data.traversal("summer")}
        self.options = vx.SequenceOptions(ks=(1,))
        self.model = vx.deploy(self.ckpt, "props", 4, reference_images=self.reference)
        self.folder = folder
        vx.save_checkpoint(folder / "net.npz", self.ckpt)
        vx.save_fixed_point(folder / "model.npz", self.model)


@pytest.fixture(scope="module")
def fx(tmp_path_factory) -> Fixtures:
    threads = torch.get_num_threads()
    yield Fixtures(tmp_path_factory.mktemp("api"))
    torch.set_num_threads(threads)


def calls(f: Fixtures) -> dict[str, tuple[Any, dict[str, Any]]]:
    sr = f.ckpt.calibration
    counts = np.ones((len(f.places), sr.shape[0]))
    scores = np.random.default_rng(0).random((3, len(f.places)))
    layout = vx.module_layout(f.cfg, len(f.places))
    return {
        "evaluate_float": (
            vx.evaluate_float,
            dict(ckpt=f.ckpt, query_images=f.winter, query_place_ids=f.places, traversal="winter", options=f.options),
        ),
        "evaluate_fixed_point": (
            vx.evaluate_fixed_point,
            dict(model=f.model, query_images=f.winter, query_place_ids=f.places, traversal="winter", options=f.options),
        ),
        "query_spikes": (vx.query_spikes, dict(images=f.winter, place_ids=f.places, traversal="winter", cfg=f.cfg)),
        "readout_rows": (
            vx.readout_rows,
            dict(
                calibration=sr,
                query_counts=counts,
                reference_place_ids=f.places,
                query_place_ids=f.places,
                options=f.options,
                config=f.cfg,
            ),
        ),
        "regularise": (vx.regularise, dict(sr=sr, sq=counts, layout=layout)),
        "module_count": (vx.module_count, dict(n_places=10, module_size=3)),
        "module_regions": (vx.module_regions, dict(n_places=10, module_size=3)),
        "module_layout": (vx.module_layout, dict(cfg=f.cfg, n_places=len(f.places))),
        "select_places": (vx.select_places, dict(dataset=f.data, place_ids=f.places[:2])),
        "quantize_checkpoint": (
            vx.quantize_checkpoint,
            dict(ckpt=f.ckpt, ckpt_sha256="props", bits=4, options=vx.QuantiseOptions()),
        ),
        "deploy": (
            vx.deploy,
            dict(ckpt=f.ckpt, ckpt_sha256="props", bits=4, options=vx.QuantiseOptions(calibration="float")),
        ),
        "decide": (vx.decide, dict(scores=scores, strategy="wprob")),
        "strategy_scores": (vx.strategy_scores, dict(sr=sr, sq=counts, strategy="weighted", gamma=0.5)),
        "aggregate": (vx.aggregate, dict(prob=scores / scores.sum(1, keepdims=True), k=2, velocity=1.0)),
        "sad_distances": (vx.sad_distances, dict(reference=f.winter, queries=f.winter)),
        "sad_distribution": (vx.sad_distribution, dict(distances=scores)),
        "pr_metrics": (vx.pr_metrics, dict(correct=np.array([True, False]), confidence=np.array([0.5, 0.2]))),
        "load_checkpoint": (vx.load_checkpoint, dict(path=f.folder / "net.npz")),
        "load_fixed_point": (vx.load_fixed_point, dict(path=f.folder / "model.npz")),
        "save_checkpoint": (vx.save_checkpoint, dict(path=f.folder / "out.npz", ckpt=f.ckpt)),
        "save_fixed_point": (vx.save_fixed_point, dict(path=f.folder / "out_model.npz", model=f.model)),
        "IntegerNetwork": (vx.IntegerNetwork, dict(model=f.model)),
        "FloatNetwork": (
            vx.FloatNetwork.from_arrays,
            dict(weights=f.ckpt.weights, thresholds=f.ckpt.thresholds, cfg=f.cfg, device=torch.device("cpu")),
        ),
    }


def arguments() -> list[tuple[str, str]]:
    names = {
        "evaluate_float": ("ckpt", "query_images", "query_place_ids", "traversal", "options"),
        "evaluate_fixed_point": ("model", "query_images", "query_place_ids", "options"),
        "query_spikes": ("images", "place_ids", "traversal", "cfg"),
        "readout_rows": ("calibration", "query_counts", "reference_place_ids", "query_place_ids", "options", "config"),
        "regularise": ("sr", "sq", "layout"),
        "module_count": ("n_places", "module_size"),
        "module_regions": ("n_places", "module_size"),
        "module_layout": ("cfg", "n_places"),
        "select_places": ("dataset", "place_ids"),
        "quantize_checkpoint": ("ckpt", "ckpt_sha256", "bits", "options"),
        "deploy": ("ckpt", "ckpt_sha256", "bits", "options"),
        "decide": ("scores", "strategy"),
        "strategy_scores": ("sr", "sq", "strategy"),
        "aggregate": ("prob", "k", "velocity"),
        "sad_distances": ("reference", "queries"),
        "sad_distribution": ("distances",),
        "pr_metrics": ("correct", "confidence"),
        "load_checkpoint": ("path",),
        "load_fixed_point": ("path",),
        "save_checkpoint": ("path", "ckpt"),
        "save_fixed_point": ("path", "model"),
        "IntegerNetwork": ("model",),
        "FloatNetwork": ("weights", "thresholds", "cfg", "device"),
    }
    return [(function, arg) for function, args in names.items() for arg in args]


@pytest.mark.parametrize(("function", "arg"), arguments())
@FAST
@given(value=BAD)
def test_a_bad_argument_works_or_is_the_projects_error(fx, function, arg, value, monkeypatch):
    monkeypatch.chdir(fx.folder)  # a drawn text is a path here for save_* and load_*
    call, kwargs = calls(fx)[function]
    kwargs[arg] = value
    try:
        call(**kwargs)
    except VprError:
        pass


PIXEL = st.sampled_from([math.nan, math.inf, -math.inf])


@FAST
@given(pixel=PIXEL, row=st.integers(0, 4), column=st.integers(0, 783))
def test_nan_or_infinite_pixels_are_refused_everywhere(fx, pixel, row, column):
    images = fx.winter.copy()
    images[row, column] = pixel
    with pytest.raises(VprError, match="NaN or infinite"):
        vx.query_spikes(images, fx.places, "winter", fx.cfg)
    with pytest.raises(VprError, match="NaN or infinite"):
        vx.evaluate_float(fx.ckpt, images, fx.places, "winter", fx.options)
    with pytest.raises(VprError, match="NaN or infinite"):
        vx.evaluate_fixed_point(fx.model, images, fx.places, "winter", fx.options)
    data = vx.Dataset(**{**fx.data.__dict__, "images": {"summer": images, "winter": fx.winter}})
    with pytest.raises(VprError, match="NaN or infinite"):
        vx.train_and_calibrate(data, ["summer"], fx.cfg, progress=False)


@FAST
@given(n_places=st.integers(1, 12))
def test_readout_rows_needs_a_calibration_of_the_reference_places(fx, n_places):
    neurons = 4
    ids = np.arange(12)
    calibration = np.ones((neurons, n_places), dtype=np.int64)
    call = lambda: vx.readout_rows(calibration, np.ones((12, neurons)), ids, ids, fx.options, fx.cfg)  # noqa: E731
    if n_places == 12:
        assert len(call()) == 3
    else:
        with pytest.raises(vx.InvalidValueError, match="calibration covers"):
            call()


def tiles(regions: np.ndarray) -> bool:
    return (
        regions[0, 0] == 0
        and bool(np.all(regions[:, 1] > regions[:, 0]))
        and bool(np.all(regions[1:, 0] == regions[:-1, 1]))
    )


@settings(max_examples=40, deadline=None)
@given(
    regions=arrays(np.int64, st.tuples(st.integers(1, 4), st.just(2)), elements=st.integers(-1, 8)),
    fraction=st.booleans(),
)
def test_a_layout_is_accepted_exactly_when_its_regions_tile_the_places(regions, fraction):
    given_regions = regions + 0.5 if fraction else regions
    if tiles(regions) and not fraction:
        layout = vx.ModuleLayout(given_regions, group=2, hyperactive_share=0.5)
        n_places = int(regions[-1, 1])
        sr = np.ones((layout.n_neurons, n_places))
        weighted, _ = vx.regularise(sr, np.ones((1, layout.n_neurons)), layout)
        assert weighted.shape == sr.shape
    else:
        with pytest.raises(vx.InvalidValueError, match="regions"):
            vx.ModuleLayout(given_regions, group=2, hyperactive_share=0.5)


LABELS = st.one_of(st.text(max_size=12), st.sampled_from(["my net", "", "a" * 129, "ok-label_1"]))
TRAVERSALS = st.one_of(
    st.lists(st.text(max_size=6), max_size=3), st.sampled_from(["summer", ["summer", "summer"], ["summer"]])
)


@FAST
@given(label=LABELS, exponent=st.integers(-200, 20), traversals=TRAVERSALS)
def test_a_model_is_written_only_if_it_reads_back_equal(fx, label, exponent, traversals):
    model = vx.FixedPointModel(
        **{
            **fx.model.__dict__,
            "source_sha256": label,
            "scale_exponent": exponent,
            "reference_traversals": traversals,
        }
    )
    path = fx.folder / "round.npz"
    path.unlink(missing_ok=True)
    try:
        vx.save_fixed_point(path, model)
    except VprError:
        assert not path.exists()  # refused before anything was written
        return
    back = vx.load_fixed_point(path)
    assert back.source_sha256 == label and back.scale_exponent == exponent
    assert back.reference_traversals == list(traversals)
    assert np.array_equal(back.weight_mantissa, model.weight_mantissa)


@FAST
@given(traversals=TRAVERSALS, source=st.one_of(st.none(), st.text(max_size=8)))
def test_a_checkpoint_is_written_only_if_it_reads_back_equal(fx, traversals, source):
    ckpt = vx.Checkpoint(
        **{**fx.ckpt.__dict__, "reference_traversals": traversals, "data": {**fx.ckpt.data, "source": source}}
    )
    path = fx.folder / "round_ckpt.npz"
    path.unlink(missing_ok=True)
    try:
        vx.save_checkpoint(path, ckpt)
    except VprError:
        assert not path.exists()
        return
    back = vx.load_checkpoint(path)
    assert back.reference_traversals == list(traversals) and back.data == ckpt.data
    assert np.array_equal(back.weights, ckpt.weights)


def test_deploy_refuses_a_label_no_reader_accepts(fx):
    with pytest.raises(vx.InvalidValueError, match="source_sha256"):
        vx.deploy(fx.ckpt, "my net", 4, vx.QuantiseOptions(calibration="float"))


def test_tiny_weights_are_refused_at_quantisation_not_at_reading(fx):
    ckpt = vx.Checkpoint(**{**fx.ckpt.__dict__, "weights": np.full_like(fx.ckpt.weights, 1e-31)})
    with pytest.raises(vx.InvalidValueError, match="scale_exponent"):
        vx.quantize_checkpoint(ckpt, "tiny", 4, vx.QuantiseOptions())


@settings(max_examples=30, deadline=None)
@given(depth=st.integers(1, 3 * JSON_MAX_DEPTH), digits=st.integers(1, 3 * JSON_MAX_DIGITS))
def test_json_within_limits_parses_and_beyond_them_is_refused(depth, digits):
    text = "[" * (depth - 1) + "9" * digits + "]" * (depth - 1)  # depth - 1 nested lists (the limit counts lists)
    if depth - 1 <= JSON_MAX_DEPTH and digits <= JSON_MAX_DIGITS:
        value = parse_json(text, "x")
        for _ in range(depth - 1):
            value = value[0]
        assert value == int("9" * digits)
    else:
        with pytest.raises(vx.InvalidValueError, match="x: JSON|JSON integer"):
            parse_json(text, "x")


def test_very_deep_json_is_refused_not_a_recursion_error():
    with pytest.raises(vx.InvalidValueError, match="nested deeper"):
        parse_json("[" * 5000 + "]" * 5000, "header")
    with pytest.raises(vx.InvalidValueError, match="digits"):
        parse_json("1" * 5001, "header")


@settings(max_examples=60, deadline=None)
@given(text=st.text(max_size=8))
def test_numbers_in_text_are_ascii_decimal_only(text):
    plain = text.isascii() and text.isdigit() and 0 < len(text) <= 19
    assert (ascii_uint(text) == int(text)) if plain else ascii_uint(text) is None
    for exotic in ("²", "٣", "３", "1_000", " 7", "7 ", "+7", ""):
        assert ascii_uint(exotic) is None and ascii_int(exotic) is None
    assert ascii_int("-12") == -12


def test_the_leftovers_of_the_api_campaign_are_refused_or_exact(fx):
    """tools/bad_input_api.py's last foreign and accepted cases: each argument named, or the exact result."""
    prob = np.random.default_rng(1).random((4, 5))
    prob /= prob.sum(1, keepdims=True)
    for strategy in (np.zeros(3), ["wprob"], None):
        with pytest.raises(vx.InvalidValueError, match="strategy"):
            vx.decide(prob, strategy)
        with pytest.raises(vx.InvalidValueError, match="strategy"):
            vx.strategy_scores(fx.ckpt.calibration, np.ones((2, fx.ckpt.calibration.shape[0])), strategy, 0.5)
    for velocity in (True, np.array([True, False, True, True])):
        with pytest.raises(vx.InvalidValueError, match="velocity"):
            vx.aggregate(prob, 2, velocity)
    np.testing.assert_array_equal(vx.aggregate(prob, 10**30, 1.5), vx.aggregate(prob, 4, 1.5))  # W_j stops at 0
    with pytest.raises(vx.InvalidValueError, match="place_ids"):
        vx.select_places(fx.data, [])
    with pytest.raises(vx.InvalidValueError, match="progress"):
        vx.train_and_calibrate(fx.data, ["summer"], fx.cfg, progress=np.ones(3))
    for device in (object(), "no-such-device", 3):
        with pytest.raises(vx.InvalidValueError, match="device"):
            vx.FloatNetwork.from_arrays(fx.ckpt.weights, fx.ckpt.thresholds, fx.cfg, device)
    assert vx.FloatNetwork.from_arrays(fx.ckpt.weights, fx.ckpt.thresholds, fx.cfg, "cpu").weights.device.type == "cpu"


def test_the_regressions_since_the_guards_moved_are_refused_at_the_edge(fx, tmp_path):
    """Issue 45: degenerate arguments that held five days ago, each refused in one project error naming it."""
    with pytest.raises(vx.InvalidValueError, match="no query"):
        vx.aggregate(np.zeros((0, 5)), 3, 1.0)
    with pytest.raises(vx.InvalidValueError, match="more than once"):
        vx.select_places(fx.data, [fx.places[0], fx.places[0]])
    for dt in (0, 0.0, -1e-4, float("nan"), 10**30, True):
        with pytest.raises(vx.InvalidValueError, match="dt"):
            vx.write_nir(fx.model, tmp_path / "m.nir", dt=dt)
    with pytest.raises(vx.InvalidValueError, match="empty name between dots"):
        vx.Config().replace(**{"train..epochs": 2})
    with pytest.raises(vx.InvalidValueError, match="is a section"):
        vx.Config().replace(**{"early": {"spikes": 5}})
    for network in (None, "net.npz", [1], float("nan")):
        with pytest.raises(vx.InvalidValueError, match="network must be"):
            vx.Localizer(network)
    for threshold in (float("nan"), "0.5", [0.5], 1.5, -0.1):
        with pytest.raises(vx.InvalidValueError, match="threshold"):
            vx.Localizer(fx.ckpt, threshold=threshold)
    robot = vx.Localizer(fx.ckpt, threshold=0.5)
    for frame in (np.zeros((0, 0), np.uint8), np.zeros((4, 4, 3), np.uint8), None):
        with pytest.raises(vx.InvalidValueError, match="frame must be"):
            robot.push(frame)
    for source in (5, None, b"frames", ""):
        with pytest.raises(vx.InvalidValueError, match="source must be a path"):
            vx.iter_frames(source)
