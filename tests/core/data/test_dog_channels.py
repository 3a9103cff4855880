"""DoG ON/OFF input channels: the equation, the layout, the config that asks for them, the whole chain."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from vprsnn_export.cli import main
from vprsnn_export.config import Config, preset
from vprsnn_export.data.preprocess import dog_on_off, normalise_resized
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.io.checkpoint import load_checkpoint


def test_on_and_off_follow_the_equation_and_never_overlap():
    rng = np.random.default_rng(3)
    images = rng.integers(0, 256, size=(4, 28, 28), dtype=np.uint8)
    out = dog_on_off(images, 1.0, 2.0)
    assert out.shape == (4, 28, 56) and out.dtype == np.float32
    on, off = out[:, :, :28], out[:, :, 28:]
    assert np.all((on == 0) | (off == 0)) and np.allclose(out.reshape(4, -1).max(axis=1), 1.0)
    first = images[0].astype(np.float32)
    blur = [cv2.GaussianBlur(first, (0, 0), s, borderType=cv2.BORDER_REFLECT) for s in (1.0, 2.0)]
    response = blur[0] - blur[1]
    np.testing.assert_allclose(on[0] - off[0], response / np.abs(response).max(), rtol=1e-5, atol=1e-6)


def test_a_flat_image_gives_zeros_not_nan():
    out = dog_on_off(np.full((1, 28, 28), 77, dtype=np.uint8), 1.0, 2.0)
    assert np.all(out == 0)


def test_the_config_asks_for_twice_the_inputs():
    cfg = preset("dog")
    assert cfg.network.n_inputs == 1568 and cfg.preprocess.channels == "dog_on_off"
    flat = normalise_resized(np.zeros((2, 28, 28), dtype=np.uint8), cfg.preprocess)
    assert flat.shape == (2, 1568)
    with pytest.raises(InvalidValueError, match="must equal 2 channel"):
        preset("paper").replace(**{"preprocess.channels": "dog_on_off"})
    with pytest.raises(InvalidValueError, match="channels"):
        Config().replace(**{"preprocess.channels": "edges"})
    with pytest.raises(InvalidValueError, match="below dog_sigma_surround"):
        preset("dog").replace(**{"preprocess.dog_sigma_centre": 3.0})
    with pytest.raises(InvalidValueError, match="unknown preset"):
        preset("nope")
    assert preset("dog") == Config() and preset("paper").network.n_inputs == 784
    assert preset("paper").preprocess.channels == "intensity"


def test_the_whole_chain_runs_with_dog_channels(tmp_path):
    ckpt = tmp_path / "dog.npz"
    tiny = ["--timesteps", "30", "--epochs", "2", "--neurons", "32", "--quiet"]
    assert (
        main(["train", "--data", "synthetic:12", "--reference", "summer", "--preset", "dog", "--out", str(ckpt), *tiny])
        == 0
    )
    assert load_checkpoint(ckpt).config.network.n_inputs == 1568
    report = [
        "--bits",
        "8,4",
        "--k",
        "1,3",
        "--reference-queries",
        "2",
        "--report",
        str(tmp_path / "report"),
        "--quiet",
    ]
    assert main(["verify", str(ckpt), "--query", "winter", *report]) in (0, 1)  # 1: a tolerance missed, not an error
    from vprsnn_export.runtime.report import load_report

    loaded = load_report(tmp_path / "report")
    assert all(result.cross_implementation.passed for result in loaded.runs[0].bits)
