"""Frames in time order from a folder of images, a video, stdin, a ROS bag or an event-camera recording.

Each frame comes out as ``(name, grey)``: a display name (file name, ``video.mp4#17``) and a 2-D uint8 image of
any size, which the localiser resizes and preprocesses like the training data. The sources:

* a **folder**: its image files (``IMAGE_SUFFIXES``) in *natural* name order (``frame2.png`` before
  ``frame10.png``): name frames so that this is their time order;
* a **video file** (``VIDEO_SUFFIXES``), decoded frame by frame with ``cv2.VideoCapture``;
* ``-``: **image paths on stdin**, one a line (at most ``MAX_LINE`` characters, blank lines skipped), read as
  they arrive, so another process can push frames while the localiser runs; raw pixels are not accepted (a
  path names the frame in the output and carries its own size);
* a **ROS bag** (:mod:`.bags`) or an **event-camera recording** binned into count frames (:mod:`.events`).

An image's header is checked against the memory limit before it is decoded; what OpenCV or FFmpeg print while
decoding never reaches the terminal (an error quotes it).
"""

from __future__ import annotations

import re
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import TextIO

import numpy as np

from ..errors import DataError, InvalidValueError
from .bags import bag_frames, is_bag
from .events import EVENT_SUFFIXES, EventWindow, event_frames
from .preprocess import captured_stderr, decoder_said, read_grey_image

IMAGE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp"})
VIDEO_SUFFIXES = frozenset({".mp4", ".avi", ".mkv", ".mov", ".webm", ".mpg", ".mpeg", ".m4v"})
STDIN = "-"
MAX_LINE = 4096  # characters in one stdin line: PATH_MAX on Linux, longer than any path that can be opened
_DIGITS = re.compile(r"(\d+)")


def natural_key(name: str) -> tuple:
    """Sort key that orders the digit runs of a name by value: ``f2`` < ``f10`` (ties: the plain name)."""
    return tuple((0, int(p), "") if p.isdigit() else (1, 0, p.lower()) for p in _DIGITS.split(name) if p), name


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
    """A frame OpenCV decoded, (H, W) grey or (H, W, 3|4) BGR(A), as 2-D greyscale (the localiser refuses one
    that is not uint8)."""
    if frame.ndim == 2:
        return frame
    import cv2

    return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY if frame.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)


def video_frames(path: str | Path) -> Iterator[tuple[str, np.ndarray]]:
    """Frames of a video file in order, as ``("name#index", grey)``; DataError when OpenCV cannot open it, and after
    the last frame when the video ended more than one frame short of the count its container declares (a cut
    or damaged file: the frames before are decided, the run still ends with the error, quoting the decoder)."""
    import cv2  # here, not at import: OpenCV takes 50-70 ms to load, and `--help` reads no video

    path = Path(path)
    with captured_stderr() as noise:
        capture = cv2.VideoCapture(str(path))
    try:
        if not capture.isOpened():
            raise DataError(
                f"cannot open this video (OpenCV's VideoCapture could not decode it{decoder_said(noise)})", path
            )
        declared = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))  # <= 0 where the container does not say
        index = 0
        while True:
            with captured_stderr() as noise:
                ok, frame = capture.read()
            if not ok:
                break
            yield f"{path.name}#{index}", to_grey(frame)
            index += 1
        if index == 0:
            raise DataError(f"the video holds no frames{decoder_said(noise)}", path)
        if index + 1 < declared:
            raise DataError(
                f"the video ended after {index} of the {declared} frames it declares: truncated or damaged"
                f"{decoder_said(noise)}",
                path,
            )
    finally:
        capture.release()


def stdin_frames(stream: TextIO) -> Iterator[tuple[str, np.ndarray]]:
    """One image path per line of ``stream``, decoded as it arrives (blank lines skipped); a line of more than
    :data:`MAX_LINE` characters is refused once that many are read (memory stays bounded)."""
    while True:
        try:
            line = stream.readline(MAX_LINE + 1)
        except UnicodeDecodeError as exc:
            raise DataError(
                f"stdin is not text in its encoding ({exc.encoding}): give one image path per line"
            ) from None
        if not line:
            return
        if len(line) > MAX_LINE:
            raise DataError(f"a line on stdin is longer than {MAX_LINE} characters: give one image path per line")
        if path := line.strip():
            yield path, read_grey_image(Path(path), "a frame path read from stdin")


def iter_frames(
    source: str | Path,
    stdin: TextIO | None = None,
    *,
    topic: str | None = None,
    events: EventWindow | None = None,
    shape: tuple[int, int] | None = None,
) -> Iterator[tuple[str, np.ndarray]]:
    """The frames of ``source``: a folder of images, a video file, ``-`` (paths on ``stdin``), a ROS bag (its image
    topic, or ``topic``) or an event recording (binned by ``events``; ``shape``: the sensor's (height, width))."""
    if not isinstance(source, str | Path) or not str(source):
        raise InvalidValueError(
            f"source must be a path (str or Path) or '-', got {type(source).__name__} {source!r:.40}"
        )
    path = Path(source)
    for misplaced, option in (
        (topic is not None and not is_bag(path), "--topic is for a ROS bag (a .bag file or a ROS 2 bag folder)"),
        (
            events is not None and path.suffix.lower() not in EVENT_SUFFIXES,
            f"--event-window-us / --event-count are for an event recording ({', '.join(sorted(EVENT_SUFFIXES))})",
        ),
    ):
        if misplaced:
            raise DataError(option, path)
    if str(source) == STDIN:
        return stdin_frames(sys.stdin if stdin is None else stdin)
    if is_bag(path):
        return bag_frames(path, topic)
    if path.is_file() and path.suffix.lower() in EVENT_SUFFIXES:
        if events is None:
            raise DataError(
                "not a video or bag; read as an event recording, it is binned into frames by --event-window-us or "
                "--event-count",
                path,
            )
        return event_frames(path, events, shape)
    if path.is_dir():
        return ((p.name, read_grey_image(p)) for p in image_files(path))
    if not path.is_file():
        raise DataError("no such folder or file (--frames takes a folder of images, a video, a bag, events or -)", path)
    if path.suffix.lower() in VIDEO_SUFFIXES:
        return video_frames(path)
    raise DataError(
        f"not a video ({', '.join(sorted(VIDEO_SUFFIXES))}), ROS bag (.bag) or event recording "
        f"({', '.join(sorted(EVENT_SUFFIXES))}); --frames also takes a folder of images or - (image paths on stdin)",
        path,
    )
