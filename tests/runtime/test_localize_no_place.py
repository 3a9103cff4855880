"""A frame that carries no place (1x1, flat grey, black; a silent input or network) gets no decision (issue 31)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from vprsnn_export.cli import main
from vprsnn_export.config import Config
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.synthetic import synthetic_route
from vprsnn_export.io.checkpoint import save_checkpoint
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.localize import NO_PLACE, Localizer, input_spikes, no_place_reasons
from vprsnn_export.trainer.pipeline import train_and_calibrate

TINY = {"encoder.timesteps": 40, "train.epochs": 2, "network.n_neurons": 16}


@pytest.fixture(scope="module")
def network():
    cfg = Config().replace(**TINY)
    data = load_dataset("synthetic:24", ["summer", "winter"], cfg.preprocess)
    return train_and_calibrate(data, ["summer"], cfg, progress=False), synthetic_route(24, ("winter",))["winter"]


def blank_frames(like: np.ndarray) -> dict[str, np.ndarray]:
    return {
        "flat": np.full_like(like, 128),
        "one-pixel": np.full((1, 1), 77, np.uint8),
        "black": np.zeros_like(like),
        "white": np.full_like(like, 255),
    }


@pytest.mark.parametrize("options", [SequenceOptions(), SequenceOptions(ks=(3,))], ids=["k1", "k3"])
def test_a_frame_without_contrast_is_never_a_place(network, options):
    ckpt, grey = network
    localizer = Localizer(ckpt, options=options, threshold=0.0)  # a threshold that accepts every decision
    textured = [localizer.push(g) for g in grey[:4]]
    assert all(d.accepted and d.reason is None for d in textured)  # the test can fail: real frames are decided
    for name, frame in blank_frames(grey[0]).items():
        decision = localizer.push(frame, name)
        assert (decision.place_id, decision.accepted, decision.confidence) == (None, False, 0.0), name
        assert decision.reason == "no contrast"
        assert decision.to_dict()["reason"] == "no contrast"
    assert "reason" not in textured[0].to_dict()


def test_the_batch_gives_the_same_answers(network):
    ckpt, grey = network
    frames = [*grey[:3], blank_frames(grey[0])["flat"], *grey[3:6]]
    pushed = Localizer(ckpt, options=SequenceOptions(ks=(3,)), threshold=0.0)
    batched = Localizer(ckpt, options=SequenceOptions(ks=(3,)), threshold=0.0)
    one = [pushed.push(f) for f in frames]
    assert [(d.place_id, d.reason) for d in one] == [(d.place_id, d.reason) for d in batched.run_batch(frames)]
    assert one[3].reason == "no contrast" and one[4].place_id is not None


def test_silent_input_and_silent_network_are_named():
    spikes = torch.zeros((3, 5, 4), dtype=torch.uint8)
    spikes[1:, 0, 0] = 1
    counts = np.array([[0, 0], [0, 0], [0, 2]])
    assert input_spikes(spikes).tolist() == [0, 1, 1]
    assert no_place_reasons(np.zeros(3, bool), input_spikes(spikes), counts) == [NO_PLACE[1], NO_PLACE[2], None]
    assert no_place_reasons(np.array([True, False, False]), input_spikes(spikes), counts)[0] == NO_PLACE[0]


def test_the_command_writes_no_decision_for_a_flat_frame(network, tmp_path, capsys):
    ckpt, grey = network
    cv2 = pytest.importorskip("cv2")
    ckpt_path = save_checkpoint(tmp_path / "net.npz", ckpt)
    frames = tmp_path / "frames"
    frames.mkdir()
    cv2.imwrite(str(frames / "0.png"), grey[0])
    cv2.imwrite(str(frames / "1.png"), blank_frames(grey[0])["flat"])
    assert main(["localize", str(ckpt_path), "--frames", str(frames), "--threshold", "0", "--quiet"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert lines[0]["accepted"] and "reason" not in lines[0]
    assert (lines[1]["place_id"], lines[1]["accepted"], lines[1]["reason"]) == (None, False, "no contrast")
