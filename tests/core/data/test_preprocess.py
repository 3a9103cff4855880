"""Preprocessing: INTER_AREA resize, per-patch min-max normalisation, row-major flattening, image decoding."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from vprsnn_export.config import PreprocessConfig, preset
from vprsnn_export.data.preprocess import patch_normalise, preprocess_images, read_grey_image, resize_image
from vprsnn_export.errors import DataError

CFG = preset("paper").preprocess  # the patch-normalised intensity channel these tests pin


def _one(image: np.ndarray, cfg: PreprocessConfig = CFG) -> np.ndarray:
    return preprocess_images(image[None].astype(np.uint8), cfg)[0].reshape(cfg.image_size, cfg.image_size)


def test_output_shape_dtype_and_range() -> None:
    grey = np.random.default_rng(0).integers(0, 256, (5, 32, 64), dtype=np.uint8)
    out = preprocess_images(grey, CFG)
    assert out.shape == (5, 784)
    assert out.dtype == np.float32
    assert out.min() >= 0.0 and out.max() <= 1.0
    patches = out.reshape(5, 4, 7, 4, 7)
    assert np.allclose(patches.min(axis=(2, 4)), 0.0) and np.allclose(patches.max(axis=(2, 4)), 1.0)


def test_flat_patch_becomes_zero() -> None:
    out = _one(np.full((28, 28), 137))
    assert np.array_equal(out, np.zeros((28, 28), np.float32))


def test_two_value_patch_becomes_zero_one() -> None:
    image = np.full((28, 28), 40)
    image[0:7, 0:7] = 90
    image[3, 4] = 200
    out = _one(image)
    expected = np.zeros((28, 28), np.float32)
    expected[3, 4] = 1.0
    assert np.array_equal(out, expected)


def test_hand_computed_patch_and_independence() -> None:
    image = np.zeros((28, 28))
    image[7:14, 14:21] = 100
    image[7, 14] = 50
    image[8, 15] = 200
    image[21:28, 21:28] = np.arange(49).reshape(7, 7) + 10
    out = _one(image)
    block = out[7:14, 14:21]
    assert block[0, 0] == pytest.approx(0.0) and block[1, 1] == pytest.approx(1.0)
    assert block[2, 2] == pytest.approx((100 - 50) / 150)
    assert np.allclose(out[21:28, 21:28], np.arange(49).reshape(7, 7) / 48)
    assert not out[:7, :].any()


def test_flatten_is_row_major() -> None:
    image = np.zeros((28, 28))
    image[9, 17] = 255
    flat = preprocess_images(image[None].astype(np.uint8), CFG)[0]
    assert flat.argmax() == 9 * 28 + 17 and flat.sum() == 1.0


def test_matches_per_patch_loop() -> None:
    grey = np.random.default_rng(1).integers(0, 256, (3, 28, 28), dtype=np.uint8)
    grey[1, 7:14, 7:14] = 9
    out = preprocess_images(grey, CFG).reshape(3, 28, 28)
    for n in range(3):
        for r in range(0, 28, 7):
            for c in range(0, 28, 7):
                patch = grey[n, r : r + 7, c : c + 7].astype(np.float64)
                span = patch.max() - patch.min()
                ref = (patch - patch.min()) / span if span else np.zeros_like(patch)
                assert np.allclose(out[n, r : r + 7, c : c + 7], ref, atol=1e-6)


def test_resize_is_inter_area() -> None:
    big = np.kron(np.arange(16, dtype=np.uint8).reshape(4, 4) * 10, np.ones((14, 14), np.uint8))
    assert np.array_equal(
        resize_image(big, 28), np.kron(np.arange(16, dtype=np.uint8).reshape(4, 4) * 10, np.ones((7, 7), np.uint8))
    )
    grey = np.random.default_rng(2).integers(0, 256, (32, 64), dtype=np.uint8)
    assert np.array_equal(resize_image(grey, 28), cv2.resize(grey, (28, 28), interpolation=cv2.INTER_AREA))


def test_without_patch_norm_scales_by_255() -> None:
    cfg = replace(CFG, patch_norm=False)
    image = np.full((28, 28), 51)
    image[0, 0] = 255
    out = _one(image, cfg)
    assert out[0, 0] == 1.0 and out[5, 5] == pytest.approx(0.2)


def test_other_sizes() -> None:
    cfg = replace(CFG, image_size=8, patch_size=4)
    out = preprocess_images(np.random.default_rng(3).integers(0, 256, (2, 32, 64), dtype=np.uint8), cfg)
    assert out.shape == (2, 64)
    assert patch_normalise(np.zeros((0, 8, 8), np.uint8), 4).shape == (0, 8, 8)


def test_rejects_wrong_input() -> None:
    with pytest.raises(DataError):
        preprocess_images(np.zeros((28, 28), np.uint8), CFG)
    with pytest.raises(DataError):
        preprocess_images(np.zeros((1, 28, 28), np.float32), CFG)


def test_read_grey_image(tmp_path: Path) -> None:
    colour = np.zeros((4, 6, 3), np.uint8)
    colour[..., 2] = 255  # red in BGR
    cv2.imwrite(str(tmp_path / "red.png"), colour)
    grey = read_grey_image(tmp_path / "red.png")
    assert grey.shape == (4, 6) and grey.dtype == np.uint8 and np.all(grey == grey[0, 0]) and grey[0, 0] > 0


def test_read_grey_image_missing(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="not found") as info:
        read_grey_image(tmp_path / "nope.png", context="row 3")
    assert "nope.png" in str(info.value) and "row 3" in str(info.value)
    assert info.value.path == tmp_path / "nope.png"


def test_read_grey_image_corrupt(tmp_path: Path) -> None:
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n this is not an image")
    with pytest.raises(DataError, match="unreadable or corrupt") as info:
        read_grey_image(bad)
    assert "bad.png" in str(info.value)
