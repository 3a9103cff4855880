"""Frames in time order from a folder of images, a video file or a list of paths on stdin.

A robot (or a recorded run) hands the localiser one greyscale frame at a time. Three sources:

* a **folder**: every image file in it (``IMAGE_SUFFIXES``), in the *natural* order of their
  names (``frame2.png`` before ``frame10.png``): name frames so that this is their time order;
* a **video file** (``VIDEO_SUFFIXES``), decoded frame by frame with ``cv2.VideoCapture``;
* ``-``: **paths on stdin**, one image path per line (blank lines skipped), read as they arrive,
  so another process can push frames while the localiser runs. Raw pixels on stdin are not
  accepted: a path names the frame in the output and carries its own size.

Each frame comes out as ``(name, grey)``: a display name (file name, ``video.mp4#17``) and a
2-D uint8 image of any size; the localiser resizes and preprocesses it like the training data.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import TextIO

import cv2
import numpy as np

from ..errors import DataError
from .preprocess import read_grey_image

IMAGE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp"})
VIDEO_SUFFIXES = frozenset({".mp4", ".avi", ".mkv", ".mov", ".webm", ".mpg", ".mpeg", ".m4v"})
STDIN = "-"
_DIGITS = re.compile(r"(\d+)")


def natural_key(name: str) -> tuple:
    """Sort key that orders the digit runs of a name by value: ``f2`` < ``f10`` (ties: the plain name)."""
    parts = _DIGITS.split(name)
    return tuple((0, int(p), "") if p.isdigit() else (1, 0, p.lower()) for p in parts if p), name


def image_files(folder: str | Path) -> list[Path]:
    """The image files directly in ``folder``, in natural name order; DataError when there are none."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError("not a folder of images", folder)
    files = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES]
    if not files:
        raise DataError(f"this folder holds no image files ({', '.join(sorted(IMAGE_SUFFIXES))})", folder)
    return sorted(files, key=lambda p: natural_key(p.name))


def to_grey(frame: np.ndarray) -> np.ndarray:
    """A decoded frame (H, W) or (H, W, 3) BGR, uint8, as 2-D uint8 greyscale."""
    array = np.asarray(frame)
    if array.dtype != np.uint8 or array.ndim not in (2, 3):
        raise DataError(f"expected a uint8 image (H, W) or (H, W, 3), got shape {array.shape} dtype {array.dtype}")
    if array.ndim == 3:
        return cv2.cvtColor(array, cv2.COLOR_BGR2GRAY if array.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    return array


def video_frames(path: str | Path) -> Iterator[tuple[str, np.ndarray]]:
    """Frames of a video file in order, as ``("name#index", grey)``; DataError when OpenCV cannot open it."""
    path = Path(path)
    capture = cv2.VideoCapture(str(path))
    try:
        if not capture.isOpened():
            raise DataError("cannot open this video (OpenCV's VideoCapture could not decode it)", path)
        index = 0
        while True:
            ok, frame = capture.read()
            if not ok:
                break
            yield f"{path.name}#{index}", to_grey(frame)
            index += 1
        if index == 0:
            raise DataError("the video holds no frames", path)
    finally:
        capture.release()


def stdin_frames(stream: TextIO) -> Iterator[tuple[str, np.ndarray]]:
    """One image path per line of ``stream``, decoded as it arrives (blank lines skipped)."""
    for line in stream:
        path = line.strip()
        if path:
            yield path, read_grey_image(Path(path), "a frame path read from stdin")


def iter_frames(source: str | Path, stdin: TextIO | None = None) -> Iterator[tuple[str, np.ndarray]]:
    """The frames of ``source``: a folder of images, a video file, or ``-`` (paths on ``stdin``)."""
    if str(source) == STDIN:
        return stdin_frames(sys.stdin if stdin is None else stdin)
    path = Path(source)
    if path.is_dir():
        return ((p.name, read_grey_image(p)) for p in image_files(path))
    if not path.is_file():
        raise DataError("no such folder or video file (--frames takes a folder of images, a video or -)", path)
    if path.suffix.lower() in VIDEO_SUFFIXES:
        return video_frames(path)
    raise DataError(
        f"not a video file (suffixes {', '.join(sorted(VIDEO_SUFFIXES))}); --frames takes a folder of images, "
        "a video or - (image paths on stdin)",
        path,
    )
