"""Image preprocessing: greyscale decode, INTER_AREA resize, patch min-max normalisation.

For an input image ``I`` (uint8, any H x W) and ``S = image_size``, ``p = patch_size``:

1. ``R = resize(I, S x S)`` with OpenCV's area interpolation (``cv2.INTER_AREA``), still uint8.
2. With ``patch_norm`` (the method): split ``R`` into the ``(S/p)**2`` non-overlapping ``p x p`` patches ``P``
   and normalise each one, ``P_hat = (P - min P) / (max P - min P)``; a flat patch (``max P == min P``) becomes
   0. Without it (an ablation): ``R_hat = R / 255``.
3. Flatten row-major: pixel ``(row, col)`` is index ``row * S + col``; float32 in [0, 1], shape ``(N, S * S)``.

With ``channels = "dog_on_off"`` step 2 is instead a centre-surround filter with ON and OFF channels (the
retina's, and an event camera's, split of a signed response):

    D = G_{sigma_c} * R - G_{sigma_s} * R          (Gaussian blurs of R as float, reflected borders)
    ON = max(D, 0),  OFF = max(-D, 0),  both divided by max(ON, OFF) over the image (0 if flat)

and image row ``r`` holds ``S`` ON values then ``S`` OFF values: pixel ``(r, c)`` is input ``r * 2S + c`` (ON)
and ``r * 2S + S + c`` (OFF), ``2 * S * S`` inputs in all.

The channels are a registry (:data:`CHANNELS`): each :class:`Channel` names its function (step 2) and its number
of channels, whence ``network.n_inputs = n_channels * S * S`` (checked by the config). Adding one is a function
and one ``CHANNELS.register`` line (docs/architecture.md).
"""

from __future__ import annotations

import os
import re
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Protocol

import numpy as np

from ..errors import DataError
from ..registry import Registry
from ..resources import check_memory, single_need
from .imageheader import image_dimensions


class PreprocessSettings(Protocol):
    """What preprocessing reads of the config (:class:`vprsnn_export.config.PreprocessConfig`): named here, not
    imported, so that the config checks its channel against :data:`CHANNELS` with no import circle."""

    @property
    def image_size(self) -> int: ...
    @property
    def patch_size(self) -> int: ...
    @property
    def patch_norm(self) -> bool: ...
    @property
    def channels(self) -> str: ...
    @property
    def dog_sigma_centre(self) -> float: ...
    @property
    def dog_sigma_surround(self) -> float: ...


DECODE_LOCK = threading.Lock()  # file descriptor 2 is process-wide: one decode captures it at a time
DATA_LOSS = "premature end"  # libjpeg: "Premature end of JPEG file", "... premature end of data segment"
OPENCV_LOG = re.compile(r"^\[[^\]]*\]\s*(?:global\s+)?\S+:\d+\s+\S+\s+")  # "[ WARN:0@0.1] global f.cpp:9 func "
SINK: list[IO[bytes]] = []  # one temporary file, reused: a new one per image costs more than the decode


@contextmanager
def captured_stderr() -> Iterator[list[str]]:
    """Send what native code writes to file descriptor 2 (libpng, libjpeg, OpenCV's log) to a list of lines,
    filled in when the block ends: an error raised after it quotes the decoder instead of the decoder printing
    above the error. Without a usable descriptor 2 nothing is captured."""
    lines: list[str] = []
    with DECODE_LOCK:
        sys.stderr.flush()
        try:
            saved = os.dup(2)
        except OSError:
            yield lines
            return
        if not SINK:
            SINK.append(tempfile.TemporaryFile())
        sink = SINK[0]
        os.dup2(sink.fileno(), 2)
        try:
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            if sink.seek(0, os.SEEK_END):
                sink.seek(0)
                text = sink.read().decode(errors="replace")
                sink.seek(0)
                sink.truncate()
                lines.extend(OPENCV_LOG.sub("", line.strip()) for line in text.splitlines() if line.strip())


def decode_grey(data: bytes) -> tuple[np.ndarray | None, list[str]]:
    """``cv2.imdecode(data, IMREAD_GRAYSCALE)`` with the decoder's stderr lines captured; None if undecodable."""
    import cv2  # here, not at import: OpenCV takes 70 ms to load, and `--help` never decodes

    with captured_stderr() as noise:
        try:
            image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
        except cv2.error:
            image = None
    return image, noise


def decoder_said(noise: list[str]) -> str:
    """The decoder's first line for a message (``": libpng error: ..."``), or '' when it said nothing."""
    return f": {noise[0]}" if noise else ""


def read_grey_image(path: Path, context: str = "") -> np.ndarray:
    """Decode one image file as 2-D uint8 greyscale (``cv2.IMREAD_GRAYSCALE``).

    Python reads the bytes and OpenCV decodes them from memory (``cv2.imdecode``), so any path Python can open
    works (a folder name that is not UTF-8 included). A missing or unreadable file, one OpenCV cannot decode, or
    one the decoder reports as cut short (libjpeg's "premature end") is a :class:`DataError` naming ``path``,
    quoting the decoder (whose stderr never reaches the terminal), with ``context`` (e.g. the manifest row).
    """
    path = Path(path)
    suffix = f" ({context})" if context else ""
    try:
        found = path.is_file()
        data = path.read_bytes() if found else b""
    except OSError as exc:  # a name too long for the file system, a path through a file, no permission
        raise DataError(f"cannot read image ({exc.strerror or exc}){suffix}", path) from None
    if not found:
        raise DataError(f"image file not found{suffix}", path)
    if not data:
        raise DataError(f"empty image file{suffix}", path)
    return decode_checked(data, path, "image", suffix)


def decode_checked(data: bytes, where: str | Path, kind: str, suffix: str = "") -> np.ndarray:
    """The encoded image ``data`` (``kind``: "image", "'png' image") as 2-D uint8 grey; a DataError at ``where``
    when OpenCV cannot decode it or the decoder reports it cut short (libjpeg's "premature end"), quoting the
    decoder, then ``suffix``. An InvalidValueError first when its header names more pixels than the memory limit
    lets a decode allocate (``4 W H`` bytes: up to 4 uint8 channels before the grey copy)."""
    size = image_dimensions(data)
    if size is not None:
        need = single_need(f"decoded image {size[0]} x {size[1]}", 4 * size[0] * size[1])
        check_memory(need, f"decoding {where}", "a smaller image would")
    image, noise = decode_grey(data)
    if image is None or image.size == 0:
        raise DataError(
            f"unreadable or corrupt {kind} (OpenCV could not decode it{decoder_said(noise)}){suffix}", where
        )
    lost = [line for line in noise if DATA_LOSS in line.lower()]
    if lost:
        raise DataError(f"truncated or corrupt {kind} (the decoder said: {lost[0]}){suffix}", where)
    return image


def resize_image(grey: np.ndarray, size: int) -> np.ndarray:
    """``R = resize(I, size x size)`` with ``cv2.INTER_AREA``; uint8 in, uint8 out."""
    import cv2

    if grey.ndim != 2 or grey.dtype != np.uint8:
        raise DataError(f"expected a 2-D uint8 greyscale image, got shape {grey.shape} dtype {grey.dtype}")
    return cv2.resize(grey, (size, size), interpolation=cv2.INTER_AREA)


def patch_normalise(resized: np.ndarray, patch_size: int) -> np.ndarray:
    """Min-max normalise every ``p x p`` patch of every ``(N, S, S)`` image independently, float32 ``(N, S, S)``:
    ``P_hat = (P - min P) / (max P - min P)`` per patch, and ``P_hat = 0`` where ``max P == min P``."""
    n, height, width = resized.shape  # multiples of patch_size: the config checks image_size
    rows, cols = height // patch_size, width // patch_size
    patches = resized.astype(np.float32).reshape(n, rows, patch_size, cols, patch_size)
    low = patches.min(axis=(2, 4), keepdims=True)
    span = patches.max(axis=(2, 4), keepdims=True) - low
    out = np.zeros_like(patches)
    np.divide(patches - low, span, out=out, where=np.broadcast_to(span > 0, patches.shape))
    return out.reshape(n, height, width)


def dog_on_off(resized: np.ndarray, sigma_centre: float, sigma_surround: float) -> np.ndarray:
    """Difference-of-Gaussians ON/OFF channels of ``(N, S, S)`` uint8 images -> ``(N, S, 2S)`` float32 in [0, 1].

    ``D = G_c * R - G_s * R``; ``ON = max(D, 0)``, ``OFF = max(-D, 0)``, side by side in each row,
    scaled by the image's largest ON or OFF value (a flat image gives zeros).
    """
    import cv2

    images = resized.astype(np.float32)
    centre = np.stack([cv2.GaussianBlur(i, (0, 0), sigma_centre, borderType=cv2.BORDER_REFLECT) for i in images])
    surround = np.stack([cv2.GaussianBlur(i, (0, 0), sigma_surround, borderType=cv2.BORDER_REFLECT) for i in images])
    response = centre - surround
    both = np.concatenate([np.maximum(response, 0), np.maximum(-response, 0)], axis=2)
    top = both.reshape(len(both), -1).max(axis=1)
    return (both / np.where(top > 0, top, 1)[:, None, None]).astype(np.float32)


def intensity_channel(resized: np.ndarray, cfg: PreprocessSettings) -> np.ndarray:
    """The paper's one channel: patch min-max normalisation, or without ``patch_norm`` (an ablation) the whole
    image scaled, ``R_hat = R / 255``; (N, S, S) float32."""
    return patch_normalise(resized, cfg.patch_size) if cfg.patch_norm else resized.astype(np.float32) / np.float32(255)


def dog_channel(resized: np.ndarray, cfg: PreprocessSettings) -> np.ndarray:
    """The ON/OFF channels of :func:`dog_on_off` at the config's two sigmas; (N, S, 2S) float32."""
    return dog_on_off(resized, cfg.dog_sigma_centre, cfg.dog_sigma_surround)


@dataclass(frozen=True)
class Channel:
    """One choice of input channels (``preprocess.channels``).

    ``normalise(resized, cfg)``: ``(N, S, S)`` uint8 -> ``(N, S, n_channels * S)`` float32 in [0, 1]
    (each image row holds the channels side by side); ``label`` names the inputs in summaries.
    """

    name: str
    n_channels: int
    normalise: Callable[[np.ndarray, PreprocessSettings], np.ndarray]
    label: str


CHANNELS: Registry[Channel] = Registry("config.preprocess.channels")
CHANNELS.register(Channel("intensity", 1, intensity_channel, "patch-normalised"))
CHANNELS.register(Channel("dog_on_off", 2, dog_channel, "DoG ON/OFF"))


def normalise_resized(resized: np.ndarray, cfg: PreprocessSettings) -> np.ndarray:
    """Steps 2-3 on already-resized ``(N, S, S)`` uint8 images, N >= 1: the input channels, flattened row-major."""
    scaled = CHANNELS.get(cfg.channels).normalise(resized, cfg)
    return np.ascontiguousarray(scaled.reshape(len(resized), -1), dtype=np.float32)


def preprocess_images(grey: np.ndarray, cfg: PreprocessSettings) -> np.ndarray:
    """``(N, H, W)`` uint8 greyscale -> ``(N, S*S)`` float32 in [0, 1] (module docstring, steps 1-3)."""
    if grey.ndim != 3 or grey.dtype != np.uint8 or not len(grey):
        raise DataError(f"expected (N, H, W) uint8 images, N >= 1, got shape {grey.shape} dtype {grey.dtype}")
    return normalise_resized(np.asarray([resize_image(image, cfg.image_size) for image in grey], dtype=np.uint8), cfg)
