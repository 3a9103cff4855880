"""Image preprocessing: greyscale decode, INTER_AREA resize, patch min-max normalisation.

For an input image ``I`` (uint8, any H x W) and ``S = image_size``, ``p = patch_size``:

1. ``R = resize(I, S x S)`` with OpenCV's area interpolation (``cv2.INTER_AREA``), still uint8.
2. With ``patch_norm`` (the method): split ``R`` into the ``(S/p)**2`` non-overlapping
   ``p x p`` patches ``P`` and normalise each one independently,
   ``P_hat = (P - min P) / (max P - min P)``; a flat patch (``max P == min P``) becomes 0.
   Without it (an ablation): ``R_hat = R / 255``.
3. Flatten row-major: the value of pixel ``(row, col)`` sits at index ``row * S + col``.

The result lies in [0, 1] as float32, shape ``(N, S * S)``.

With ``channels = "dog_on_off"`` step 2 is instead a centre-surround filter with ON and OFF
channels (the retina's, and an event camera's, split of a signed response):

    D = G_{sigma_c} * R - G_{sigma_s} * R          (Gaussian blurs of R as float, reflected borders)
    ON = max(D, 0),  OFF = max(-D, 0),  both divided by max(ON, OFF) over the image (0 if flat)

and the image row ``r`` holds ``S`` ON values then ``S`` OFF values: pixel ``(r, c)`` is input
``r * 2S + c`` (ON) and ``r * 2S + S + c`` (OFF), ``2 * S * S`` inputs in all.

The channels are a registry (:data:`CHANNELS`): each :class:`Channel` names its function
(step 2) and its number of channels, from which ``network.n_inputs`` follows
(``n_channels * S * S``, checked by the config). Adding one is a function and one
``CHANNELS.register`` line (docs/architecture.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from .errors import DataError, InvalidValueError
from .registry import Registry

if TYPE_CHECKING:
    from .config import PreprocessConfig


def read_grey_image(path: Path, context: str = "") -> np.ndarray:
    """Decode one image file as 2-D uint8 greyscale (``cv2.IMREAD_GRAYSCALE``).

    A missing file, or one OpenCV cannot decode (``cv2.imread`` returns None), raises
    a :class:`DataError` naming ``path``; ``context`` (e.g. which manifest row asked
    for it) is appended to the message.
    """
    path = Path(path)
    suffix = f" ({context})" if context else ""
    try:
        found = path.is_file()
    except OSError as exc:  # a name too long for the file system, a path through a file
        raise DataError(f"cannot read image ({exc.strerror or exc}){suffix}", path) from None
    if not found:
        raise DataError(f"image file not found{suffix}", path)
    try:
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    except cv2.error as exc:
        raise DataError(f"cannot decode image: {exc}{suffix}", path) from None
    if image is None or image.size == 0:
        raise DataError(f"unreadable or corrupt image (OpenCV could not decode it){suffix}", path)
    return image


def resize_image(grey: np.ndarray, size: int) -> np.ndarray:
    """``R = resize(I, size x size)`` with ``cv2.INTER_AREA``; uint8 in, uint8 out."""
    if grey.ndim != 2 or grey.dtype != np.uint8:
        raise DataError(f"expected a 2-D uint8 greyscale image, got shape {grey.shape} dtype {grey.dtype}")
    return cv2.resize(grey, (size, size), interpolation=cv2.INTER_AREA)


def patch_normalise(resized: np.ndarray, patch_size: int) -> np.ndarray:
    """Min-max normalise every ``p x p`` patch of every image independently.

    ``resized`` is ``(N, S, S)``; returns float32 ``(N, S, S)`` with
    ``P_hat = (P - min P) / (max P - min P)`` per patch, and ``P_hat = 0`` where ``max P == min P``.
    """
    n, height, width = resized.shape
    if height % patch_size or width % patch_size:
        raise InvalidValueError(f"image size {height}x{width} is not a multiple of patch_size {patch_size}")
    rows, cols = height // patch_size, width // patch_size
    patches = resized.astype(np.float32).reshape(n, rows, patch_size, cols, patch_size)
    low = patches.min(axis=(2, 4), keepdims=True)
    span = patches.max(axis=(2, 4), keepdims=True) - low
    out = np.zeros_like(patches)
    np.divide(patches - low, span, out=out, where=np.broadcast_to(span > 0, patches.shape))
    return out.reshape(n, height, width)


def scale_unit(resized: np.ndarray) -> np.ndarray:
    """Whole-image scaling ``R_hat = R / 255`` (the ``patch_norm = False`` ablation), float32."""
    return resized.astype(np.float32) / np.float32(255.0)


def dog_on_off(resized: np.ndarray, sigma_centre: float, sigma_surround: float) -> np.ndarray:
    """Difference-of-Gaussians ON/OFF channels of ``(N, S, S)`` uint8 images -> ``(N, S, 2S)`` float32 in [0, 1].

    ``D = G_c * R - G_s * R``; ``ON = max(D, 0)``, ``OFF = max(-D, 0)``, side by side in each row,
    scaled by the image's largest ON or OFF value (a flat image gives zeros).
    """
    images = resized.astype(np.float32)
    centre = np.stack([cv2.GaussianBlur(i, (0, 0), sigma_centre, borderType=cv2.BORDER_REFLECT) for i in images])
    surround = np.stack([cv2.GaussianBlur(i, (0, 0), sigma_surround, borderType=cv2.BORDER_REFLECT) for i in images])
    response = centre - surround
    both = np.concatenate([np.maximum(response, 0), np.maximum(-response, 0)], axis=2)
    top = both.reshape(len(both), -1).max(axis=1)
    return (both / np.where(top > 0, top, 1)[:, None, None]).astype(np.float32)


def intensity_channel(resized: np.ndarray, cfg: PreprocessConfig) -> np.ndarray:
    """The paper's one channel: patch min-max normalisation (``R / 255`` without ``patch_norm``), (N, S, S)."""
    return patch_normalise(resized, cfg.patch_size) if cfg.patch_norm else scale_unit(resized)


def dog_channels(resized: np.ndarray, cfg: PreprocessConfig) -> np.ndarray:
    """DoG ON and OFF channels with the config's sigmas, (N, S, 2S) (:func:`dog_on_off`)."""
    return dog_on_off(resized, cfg.dog_sigma_centre, cfg.dog_sigma_surround)


@dataclass(frozen=True)
class Channel:
    """One choice of input channels (``preprocess.channels``).

    ``normalise(resized, cfg)``: ``(N, S, S)`` uint8 -> ``(N, S, n_channels * S)`` float32 in [0, 1]
    (each image row holds the channels side by side); ``label`` names the inputs in summaries.
    """

    name: str
    n_channels: int
    normalise: Callable[[np.ndarray, PreprocessConfig], np.ndarray]
    label: str


CHANNELS: Registry[Channel] = Registry("config.preprocess.channels")
CHANNELS.register(Channel("intensity", 1, intensity_channel, "patch-normalised"))
CHANNELS.register(Channel("dog_on_off", 2, dog_channels, "DoG ON/OFF"))


def normalise_resized(resized: np.ndarray, cfg: PreprocessConfig) -> np.ndarray:
    """Steps 2-3 on already-resized ``(N, S, S)`` uint8 images: the input channels, flattened row-major."""
    if resized.ndim != 3 or resized.dtype != np.uint8:
        raise DataError(f"expected (N, H, W) uint8 images, got shape {resized.shape} dtype {resized.dtype}")
    if len(resized) == 0:
        raise DataError("no images to preprocess")
    scaled = CHANNELS.get(cfg.channels).normalise(resized, cfg)
    return np.ascontiguousarray(scaled.reshape(len(resized), -1), dtype=np.float32)


def preprocess_images(grey: np.ndarray, cfg: PreprocessConfig) -> np.ndarray:
    """``(N, H, W)`` uint8 greyscale -> ``(N, S*S)`` float32 in [0, 1] (module docstring, steps 1-3)."""
    if grey.ndim != 3 or grey.dtype != np.uint8:
        raise DataError(f"expected (N, H, W) uint8 images, got shape {grey.shape} dtype {grey.dtype}")
    size = cfg.image_size
    resized = np.empty((len(grey), size, size), dtype=np.uint8)
    for index, image in enumerate(grey):
        resized[index] = resize_image(image, size)
    return normalise_resized(resized, cfg)
