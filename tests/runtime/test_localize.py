"""Online localisation: causal, one frame at a time, the same decisions batched, integer == ONNX."""

from __future__ import annotations

import numpy as np
import pytest

from vprsnn_export.config import Config
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.synthetic import synthetic_route
from vprsnn_export.errors import InvalidValueError, ModelFileError
from vprsnn_export.export.quantize import QuantiseOptions
from vprsnn_export.readout.aggregation import aggregate, track_velocity
from vprsnn_export.readout.scoring import Readout, ensemble_layout
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.readout.strategies import decide
from vprsnn_export.runtime.deployment import deploy
from vprsnn_export.runtime.localize import (
    Localizer,
    PrecisionRecallCurve,
    calibration_curve,
    load_operating_point,
    operating_point,
    precision_threshold,
    save_operating_point,
)
from vprsnn_export.targets.onnx_target import write_onnx
from vprsnn_export.trainer.pipeline import train_and_calibrate

TINY = {"encoder.timesteps": 40, "train.epochs": 2, "network.n_neurons": 16}
TRACK = SequenceOptions(
    ks=(3,), velocity_candidates=(0.5, 1.0, 1.5), velocity_estimate="track", velocity_span=4, velocity_memory=5
)


@pytest.fixture(scope="module")
def networks(tmp_path_factory):
    cfg = Config().replace(**TINY)
    data = load_dataset("synthetic:24", ["summer", "winter"], cfg.preprocess)
    ckpt = train_and_calibrate(data, ["summer"], cfg, progress=False)
    model = deploy(ckpt, "0" * 64, 4, reference_images={"summer": data.traversal("summer")})
    graph = write_onnx(model, tmp_path_factory.mktemp("onnx") / "model.onnx")
    return ckpt, model, graph, data, synthetic_route(24, ("winter",))["winter"]


def answers(decisions):
    return [(d.frame, d.place_id, d.confidence, d.velocity, d.accepted) for d in decisions]


@pytest.mark.parametrize("options", [SequenceOptions(), SequenceOptions(ks=(3,)), TRACK], ids=["k1", "k3", "track"])
def test_integer_and_onnx_decide_identically_frame_by_frame(networks, options):
    _, model, graph, _, grey = networks
    integer = Localizer(model, options=options, threshold=0.5)
    onnx = Localizer(model, backend="onnx", onnx_path=graph, options=options, threshold=0.5)
    pushed = [integer.push(g) for g in grey]
    assert answers(pushed) == answers(onnx.push(g) for g in grey)
    assert answers(pushed) == answers(integer.run_batch(grey))  # one batched network run, the same decisions
    assert [d.frame for d in pushed] == list(range(24)) and all(d.latency_ms > 0 for d in pushed)


def test_the_decision_is_the_causal_aggregate_of_the_recent_frames(networks):
    ckpt, _, _, _, grey = networks
    localizer = Localizer(ckpt, options=TRACK)
    decisions = localizer.run_batch(grey)
    wprob = np.stack([localizer.readout.wprob(c) for c in localizer.counts(_inputs(localizer, grey), 0)])
    velocity, _ = track_velocity(wprob, 3, np.asarray(TRACK.velocity_candidates), 4, memory=5)
    assert [d.velocity for d in decisions] == pytest.approx(velocity.tolist())
    for j in (0, 5, 23):  # frame j's decision uses frames j-2..j only, at its tracked velocity
        final = aggregate(wprob[max(0, j - 2) : j + 1], 3, velocity[j])[-1:]
        index, confidence = decide(final, "wprob")
        assert decisions[j].place_id == int(ckpt.reference_place_ids[index[0]])
        assert decisions[j].confidence == pytest.approx(confidence[0])


def _inputs(localizer, grey):
    return np.concatenate([localizer.preprocess(g) for g in grey])


def test_precision_threshold_is_the_lowest_that_keeps_precision():
    confidence = np.array([0.9, 0.8, 0.8, 0.7, 0.6, 0.0])
    correct = np.array([True, True, False, True, True, False])
    assert precision_threshold(confidence, correct, 1.0) == 0.9  # 0.8 admits a wrong decision
    assert precision_threshold(confidence, correct, 0.75) == 0.6
    assert precision_threshold(confidence, np.zeros(6, bool), 1.0) is None
    curve = PrecisionRecallCurve.of(confidence, correct)  # one point per distinct confidence > 0, descending
    assert curve.threshold.tolist() == [0.9, 0.8, 0.7, 0.6] and curve.accepted.tolist() == [1, 3, 4, 5]
    assert curve.precision.tolist() == pytest.approx([1, 2 / 3, 3 / 4, 4 / 5])
    assert curve.recall.tolist() == pytest.approx([1 / 6, 2 / 6, 3 / 6, 4 / 6])  # over all 6 queries
    assert curve.index_for(1.0) == 0 and curve.index_for(0.75) == 3 and curve.index_for(0.9) == 0
    assert curve.rows(3, n=1) == [(0.7, 0.75, 0.5, 4), (0.6, 0.8, 4 / 6, 5)]


def test_operating_point_reaches_its_precision_and_round_trips(networks, tmp_path):
    ckpt, _, _, data, _ = networks
    localizer = Localizer(ckpt, options=SequenceOptions(ks=(3,)))
    point, decisions, returned = operating_point(
        localizer, data.traversal("winter"), data.place_ids, precision=1.0, model_sha256="ab" * 32, query="winter"
    )
    assert point.threshold is not None and point.precision == 1.0 and 0 < point.recall <= 1
    accepted = [d for d in decisions if point.accepts(d.confidence, d.place_id)]
    assert accepted and all(d.place_id == data.place_ids[d.frame] for d in accepted)
    assert len(accepted) == round(point.recall * 24)
    curve = calibration_curve(decisions, data.place_ids)  # the curve it was chosen from, returned beside it
    np.testing.assert_array_equal(returned.threshold, curve.threshold)
    chosen = curve.index_for(1.0)
    assert chosen is not None and curve.threshold[chosen] == point.threshold and curve.recall[chosen] == point.recall
    assert curve.accepted[chosen] == len(accepted)
    path = save_operating_point(point, tmp_path / "net.operating-point.json")
    assert load_operating_point(path, "ab" * 32) == point
    with pytest.raises(ModelFileError, match="another model"):
        load_operating_point(path, "cd" * 32)


def test_backend_mismatches_are_one_clear_error(networks, tmp_path):
    ckpt, model, _, _, _ = networks
    with pytest.raises(InvalidValueError, match="fixed-point model"):
        Localizer(ckpt, backend="integer")
    with pytest.raises(InvalidValueError, match="--onnx"):
        Localizer(model, backend="onnx")
    other = deploy(ckpt, "1" * 64, 4, QuantiseOptions(calibration="float"))
    graph = write_onnx(other, tmp_path / "other.onnx")
    with pytest.raises(ModelFileError, match="not exported from the given model"):
        Localizer(model, backend="onnx", onnx_path=graph)
    with pytest.raises(InvalidValueError, match="--k"):
        SequenceOptions(ks=(0,))
    with pytest.raises(InvalidValueError, match="one k"):
        Localizer(ckpt, options=SequenceOptions(ks=(1, 3)))
    with pytest.raises(InvalidValueError, match="causally: choose track or window"):  # smooth waits for frames
        Localizer(ckpt, options=SequenceOptions(ks=(3,), velocity_candidates=(1.0,)))
    # the guards stop 58 left to one place: Readout.of, require_type, the frame check after np.asarray
    with pytest.raises(InvalidValueError, match="^options must be a SequenceOptions, got dict$"):
        Localizer(ckpt, options={"ks": (1,)})
    with pytest.raises(InvalidValueError, match="^search must be a SearchWindow, got int$"):
        Localizer(ckpt, search=300)
    with pytest.raises(InvalidValueError, match="a frame must be a non-empty 2-D greyscale array"):
        Localizer(ckpt).push("not a frame")


@pytest.mark.parametrize("module_size", [0, 8])
def test_the_prepared_readout_is_the_evaluation_readout(module_size):
    cfg = Config().replace(**{"network.n_neurons": 16, "train.module_size": module_size})
    rng = np.random.default_rng(3)
    neurons = 48 if module_size else 16
    calibration = rng.poisson(0.6, (neurons, 24)).astype(np.int64)
    counts = rng.poisson(0.4, (10, neurons)).astype(np.int64)
    counts[0] = 0  # a silent frame: the uniform distribution, a no-match
    layout = ensemble_layout(cfg, 24)
    readout = Readout(calibration, cfg.assignment.gamma, modules=layout)
    expected = readout.scores(counts)["wprob"]
    got = np.stack([readout.wprob(row) for row in counts])
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-15)
    assert decide(got[:1], "wprob")[0][0] == -1
