"""Adaptation from a second, unlabelled traversal (trainer/adaptation.py, train --adapt-from; issue 34)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vprsnn_export.cli import main
from vprsnn_export.commands.train import ADAPTATIONS
from vprsnn_export.config import Config
from vprsnn_export.data.encoding import adapted_inputs, firing_probabilities
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.io.checkpoint import load_checkpoint
from vprsnn_export.trainer.adaptation import (
    MECHANISMS,
    adapt_config,
    input_gain,
    parse_place_ranges,
    place_ranges,
    sequence_pairs,
)


def test_the_gain_is_the_between_to_within_variance_ratio():
    """Input 0 differs between places and never between traversals; input 1 is the reverse; input 2 both."""
    places = np.array([0.0, 1.0, 0.0, 1.0])
    a = np.stack([places, np.full(4, 0.5), places], axis=1)
    b = np.stack([places, np.array([0.0, 1.0, 1.0, 0.0]), 1 - places], axis=1)
    g = input_gain(a, b)
    within = np.array([0.0, 0.25, 1.0]) / 4
    between = np.var((a + b) / 2, axis=0)
    np.testing.assert_allclose(g, np.sqrt(between / (within + within.mean())))
    assert g[0] > g[2] and g[1] < g[0]


def test_the_encoder_applies_the_gain_then_the_images_largest_input():
    x = np.array([[0.5, 1.0, 0.25], [0.0, 0.0, 0.0], [0.2, 0.0, 0.4]], dtype=np.float32)
    g = (2.0, 0.5, 1.0)
    out = adapted_inputs(x, g)
    np.testing.assert_allclose(out[0], [1.0, 0.5, 0.25])  # g x = (1, 0.5, 0.25): its max is already 1
    np.testing.assert_array_equal(out[1], 0)  # an empty image stays empty
    np.testing.assert_allclose(out[2], [1.0, 0.0, 1.0])
    assert adapted_inputs(x, ()) is x  # no gain: the input untouched (every older checkpoint's spikes)
    cfg = Config().replace(**{"encoder.input_gain": [1.0] * 1568, "encoder.rate_scale": 0.5})
    pixels = np.random.default_rng(0).random((2, 1568)).astype(np.float32)
    expected = 0.5 * pixels / pixels.max(axis=1, keepdims=True)
    np.testing.assert_allclose(firing_probabilities(pixels, cfg.encoder).numpy(), expected, rtol=1e-6)
    with pytest.raises(InvalidValueError, match="1568"):
        adapted_inputs(x, cfg.encoder.input_gain)


def test_a_gain_is_checked_and_written_only_when_learnt():
    assert "input_gain" not in Config().to_dict()["encoder"]  # older files stay byte-identical
    cfg = Config().replace(**{"encoder.input_gain": [0.5] * 1568})
    assert Config.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    assert cfg.training_encoder.input_gain == cfg.encoder.input_gain  # STDP learns on the adapted input
    for bad, message in (([1.0] * 3, "1568"), ([-1.0] * 1568, "negative"), ([0.0] * 1568, "all-zero"), (5, "list")):
        with pytest.raises(InvalidValueError, match=f"input_gain.*{message}|{message}.*input_gain"):
            Config().replace(**{"encoder.input_gain": bad})


def test_sequence_matching_pairs_the_frames_without_labels():
    """A second traversal: the reference's images with noise; each stretch of frames is paired on its own."""
    rng = np.random.default_rng(1)
    reference = rng.random((60, 40))
    frames = reference + 0.6 * rng.random((60, 40))
    ids = np.r_[0:25, 35:60]
    paired = sequence_pairs(reference, frames[ids], ids, k=5)
    assert np.mean(paired == ids) > 0.9
    assert place_ranges(ids) == "0:25,35:25"
    np.testing.assert_array_equal(parse_place_ranges("0:25,35:25"), ids)
    with pytest.raises(InvalidValueError, match="--adapt-places"):
        parse_place_ranges("0:25,x")


def test_the_command_names_the_registered_mechanisms():
    assert ADAPTATIONS == tuple(MECHANISMS)


def test_the_traversal_adapted_to_is_never_a_reference(synthetic_data):
    with pytest.raises(InvalidValueError, match="reference"):
        adapt_config(synthetic_data, ["summer"], "summer", Config())
    with pytest.raises(InvalidValueError, match="no traversal 'autumn'"):
        adapt_config(synthetic_data, ["summer"], "autumn", Config())


SMALL = ["--timesteps", "40", "--epochs", "2", "--neurons", "20", "--quiet", "--seed", "4"]


def test_train_adapt_from_writes_the_gain_into_the_checkpoint(tmp_path, capsys):
    out = tmp_path / "adapted.npz"
    argv = ["train", "--data", "synthetic:24", "--reference", "summer", "--out", str(out), *SMALL]
    assert main([*argv, "--adapt-from", "winter", "--adapt", "gain", "--adapt-places", "0:12"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[-1].startswith("adaptation: gain learnt from 12 frames of 'winter' (places 0:12; paired by")
    ckpt = load_checkpoint(out)
    gain = np.asarray(ckpt.config.encoder.input_gain)
    assert gain.shape == (1568,) and gain.min() >= 0 and gain.std() > 0
    assert ckpt.data["adaptation"] == printed[-1].removeprefix("adaptation: ")
    assert ckpt.reference_traversals == ["summer"]  # the adapted-to traversal never becomes a reference
    assert main(["evaluate", str(out), "--query", "winter", "--quiet"]) == 0
    assert f"the network's input is adapted: {ckpt.data['adaptation']}" in capsys.readouterr().err
    plain = tmp_path / "plain.npz"
    assert main(["train", "--data", "synthetic:24", "--reference", "summer", "--out", str(plain), *SMALL]) == 0
    assert capsys.readouterr().out.splitlines()[-1].startswith("adaptation: none (no second traversal named")
    assert not np.array_equal(load_checkpoint(plain).weights, ckpt.weights)  # STDP learnt on the adapted input


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--adapt-from", "winter"], "--adapt-from TRAVERSAL and --adapt MECHANISM go together"),
        (["--adapt", "gain"], "go together"),
        (["--adapt-from", "summer", "--adapt", "gain"], "'summer' is a reference traversal"),
        (["--adapt-from", "winter", "--adapt", "gain", "--adapt-places", "5"], "--adapt-places '5'"),
    ],
)
def test_train_refuses_an_incomplete_adaptation_in_one_line(tmp_path, capsys, extra, message):
    argv = ["train", "--data", "synthetic:8", "--reference", "summer", "--out", str(tmp_path / "n.npz"), *SMALL]
    assert main([*argv, *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not (tmp_path / "n.npz").exists()


def test_the_report_shows_a_learnt_gain_as_its_range():
    from vprsnn_export.runtime.report.blocks import summarised

    plain = Config().to_dict()
    assert summarised(plain) is plain
    shown = summarised(Config().replace(**{"encoder.input_gain": [0.5] * 1567 + [2.0]}).to_dict())
    assert shown["encoder"]["input_gain"] == "1568 learnt gains from 0.5 to 2 (mean 0.501)"


def test_localize_feeds_every_backend_the_adapted_input(tmp_path):
    """The front end of `localize` encodes with the network's gain: integer and ONNX decide alike frame by frame,
    and the same weights without the gain count other spikes."""
    from dataclasses import replace

    from vprsnn_export.data.dataset import load_dataset
    from vprsnn_export.data.synthetic import synthetic_route
    from vprsnn_export.runtime.deployment import deploy
    from vprsnn_export.runtime.localize import Localizer
    from vprsnn_export.targets.onnx_target import write_onnx
    from vprsnn_export.trainer.pipeline import train_and_calibrate

    gain = np.random.default_rng(2).uniform(0.1, 2.0, 1568).tolist()
    cfg = Config().replace(
        **{"encoder.timesteps": 30, "train.epochs": 2, "network.n_neurons": 16, "encoder.input_gain": gain}
    )
    data = load_dataset("synthetic:16", ["summer", "winter"], cfg.preprocess)
    ckpt = train_and_calibrate(data, ["summer"], cfg, progress=False)
    model = deploy(ckpt, "0" * 64, 8, reference_images={"summer": data.traversal("summer")})
    assert model.config.encoder.input_gain == ckpt.config.encoder.input_gain  # quantisation keeps it
    grey = synthetic_route(16, ("winter",))["winter"]
    integer = Localizer(model)
    onnx = Localizer(model, backend="onnx", onnx_path=write_onnx(model, tmp_path / "m.onnx"))
    decided = [(d.place_id, d.confidence) for d in map(integer.push, grey)]
    assert decided == [(d.place_id, d.confidence) for d in map(onnx.push, grey)]
    inputs = np.concatenate([integer.preprocess(g) for g in grey])
    plain = replace(ckpt, config=replace(cfg, encoder=replace(cfg.encoder, input_gain=())))
    assert not np.array_equal(Localizer(ckpt).counts(inputs, 0), Localizer(plain).counts(inputs, 0))


def test_truth_pairing_follows_a_folder_ground_truth_not_the_index(tmp_path, capsys):
    """Issue 45: winter frame j is summer place (j + 3) mod 12 by the folder's ground-truth file; --adapt-pairing
    truth pairs by that file (and says so), never by the frame index."""
    import cv2

    from vprsnn_export.data.synthetic import synthetic_route

    n = 12
    route = synthetic_route(n, ("summer", "winter"))
    data = tmp_path / "data"
    for name, frames in (("summer", route["summer"]), ("winter", np.roll(route["winter"], -3, axis=0))):
        (data / name).mkdir(parents=True)
        for index, image in enumerate(frames):
            cv2.imwrite(str(data / name / f"{index:03d}.png"), image)
    truth = np.zeros((n, n), dtype=np.int64)  # GT[reference, query]: frame j of winter is place (j + 3) mod 12
    truth[(np.arange(n) + 3) % n, np.arange(n)] = 1
    (data / "summer_winter_GT.csv").write_text(
        "query,reference\n" + "".join(f"{q},{(q + 3) % n}\n" for q in range(n)), encoding="utf-8"
    )
    out = tmp_path / "net.npz"
    argv = ["train", "--data", str(data), "--reference", "summer", "--adapt-from", "winter", "--adapt", "gain"]
    tiny = ["--timesteps", "20", "--epochs", "1", "--neurons", "8", "--quiet"]
    assert main([*argv, "--adapt-pairing", "truth", *tiny, "--out", str(out)]) == 0
    record = load_checkpoint(out).data["adaptation"]
    assert "paired by ground truth summer_winter_GT.csv" in record and "0 % at their own place id" in record
    frame = data / "winter" / "003.png"
    before = frame.read_bytes()
    for over in (frame, data / "winter" / "net.npz"):  # --out over an adaptation frame, or into its folder
        capsys.readouterr()
        assert main([*argv, *tiny, "--force", "--out", str(over)]) == 2
        assert "never replaces a frame" in capsys.readouterr().err
    assert frame.read_bytes() == before
