"""Bernoulli rate encoding whose spikes are a pure function of (seed, image, presentation).

s_i[t] ~ Bernoulli(clip(rate_scale * p_i, 0, 1)) for t = 0..T-1 and i = 0..783.

Every presentation of an image (a training epoch, calibration, a query) has a *presentation key* (seed, stream,
traversal, place_id, epoch), hashed to a 63-bit seed of the image's own CPU generator that draws its uniforms
u[t, i]: the spikes of one image never depend on batching, on the other images or on the device that consumes
them. The float network, the integer simulator and the ONNX graph are all fed these same tensors.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence

import numpy as np
import torch

from ..arguments import check_place_ids, require_type
from ..config import Config, EncoderConfig
from ..errors import InvalidValueError
from ..resources import LOWER_RUN, check_memory, single_need
from .encoding_kernel import bernoulli_spikes

STREAM_QUERY = "query"
STREAM_CALIBRATE = "calibrate"


def presentation_seed(seed: int, stream: str, traversal: str, place_id: int, epoch: int = 0) -> int:
    """Hash a presentation key to a 63-bit generator seed (sha256, first 8 bytes)."""
    key = f"vprsnn/v1|{seed}|{stream}|{traversal}|{int(place_id)}|{epoch}".encode("utf-8", "surrogateescape")
    return int.from_bytes(hashlib.sha256(key).digest()[:8], "little") & ((1 << 63) - 1)


def pixel_array(images: np.ndarray | torch.Tensor, name: str = "images") -> np.ndarray:
    """The pixels as float32 when every one is a finite real number; InvalidValueError naming ``name`` otherwise
    (a NaN pixel would otherwise become a silent zero-rate input)."""
    values = images.detach().cpu().numpy() if isinstance(images, torch.Tensor) else images
    try:
        array = np.asarray(values)
    except (TypeError, ValueError) as exc:
        raise InvalidValueError(f"{name} must be an array of pixel values ({exc})") from None
    if array.dtype.kind not in "biuf":
        raise InvalidValueError(f"{name} must hold real pixel values, got dtype {array.dtype}")
    if array.dtype.kind == "f" and not np.all(np.isfinite(array)):
        raise InvalidValueError(f"{name} contain NaN or infinite pixels")
    with np.errstate(over="ignore"):  # beyond float32: +-inf, clipped to rate 0 or 1 as any large pixel
        return np.asarray(array, dtype=np.float32)


def adapted_inputs(pixels: np.ndarray, gain: Sequence[float]) -> np.ndarray:
    """The encoder's input after the learnt per-input gain g (``encoder.input_gain``), float32 (N, D):

        x'_i = g_i x_i / max_j g_j x_j      (0 for an image whose gained inputs are all 0)

    so every image keeps a largest input of 1, as the preprocessing gives it; no gain: x unchanged.
    """
    if not len(gain):
        return pixels
    if pixels.ndim != 2 or pixels.shape[1] != len(gain):
        raise InvalidValueError(f"images: expected (N, {len(gain)}) inputs for the encoder's gain, got {pixels.shape}")
    gained = pixels * np.asarray(gain, dtype=np.float32)
    top = gained.max(axis=1, keepdims=True)
    return np.divide(gained, top, out=np.zeros_like(gained), where=top > 0)


def firing_probabilities(images: np.ndarray | torch.Tensor, cfg: EncoderConfig) -> torch.Tensor:
    """p_i = clip(rate_scale * x'_i, 0, 1), shape (N, D), float32 (x': :func:`adapted_inputs`)."""
    pixels = torch.as_tensor(adapted_inputs(pixel_array(images), cfg.input_gain))
    return torch.clamp(cfg.rate_scale * pixels, 0.0, 1.0).nan_to_num(nan=0.0)


def encode(images: np.ndarray, seeds: Sequence[int], cfg: EncoderConfig) -> torch.Tensor:
    """Spike trains of shape (N, T, D), dtype uint8, on the CPU.

    Row n uses only ``images[n]`` and ``seeds[n]``: s[n, t, i] = u[n, t, i] < p[n, i] with u drawn from
    ``torch.Generator().manual_seed(seeds[n])`` (``torch.rand``), reproduced without building u by the compiled
    :func:`vprsnn_export.data.encoding_kernel.bernoulli_spikes`; with ``cfg.generator`` ``"philox"`` u is
    Philox4x32-10's of (seeds[n], t, i) (:mod:`vprsnn_export.data.philox`).
    """
    images = pixel_array(images)
    if images.ndim != 2 or len(seeds) != images.shape[0]:
        raise InvalidValueError(f"images: expected (N, D) images and N seeds, got {images.shape} and {len(seeds)}")
    n, d = images.shape
    spikes = single_need(f"input spikes {n} x {cfg.timesteps} x {d}", n * cfg.timesteps * d)
    check_memory(spikes, "encoding the spikes", LOWER_RUN)
    prob = firing_probabilities(images, cfg).numpy()
    return torch.from_numpy(bernoulli_spikes(prob, seeds, cfg.timesteps, cfg.generator))


def encode_presentations(
    images: np.ndarray,
    place_ids: Sequence[int] | np.ndarray,
    cfg: EncoderConfig,
    *,
    seed: int,
    stream: str,
    traversal: str,
    epoch: int = 0,
) -> torch.Tensor:
    """Encode a traversal's images under their presentation keys (see module docstring)."""
    place_ids = check_place_ids(place_ids)
    require_type("traversal", traversal, str)
    return encode(images, [presentation_seed(seed, stream, traversal, int(p), epoch) for p in place_ids], cfg)


def query_spikes(images: np.ndarray, place_ids: np.ndarray, traversal: str, cfg: Config) -> torch.Tensor:
    """The query presentations (N, T, inputs) uint8; every backend is fed exactly these."""
    require_type("cfg", cfg, Config)
    return encode_presentations(images, place_ids, cfg.encoder, seed=cfg.seed, stream=STREAM_QUERY, traversal=traversal)


def calibration_spikes(images: np.ndarray, place_ids: np.ndarray, traversal: str, cfg: Config) -> torch.Tensor:
    """The calibration presentations of one reference traversal (identical for every backend)."""
    require_type("cfg", cfg, Config)
    return encode_presentations(
        images, place_ids, cfg.encoder, seed=cfg.seed, stream=STREAM_CALIBRATE, traversal=traversal
    )
