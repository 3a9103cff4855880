"""Frames binned from an event-camera recording: accumulated event counts per pixel over a window.

An event camera (DVS, DAVIS) records events ``(x, y, t, p)``: pixel column and row, time and polarity. Frames
count them (LENS' DAVIS frames, tonic's ``ToFrame``): frame ``i`` is

    F_i[y, x] = min(255, #{events e in window i : (x_e, y_e) = (x, y)})        (both polarities, uint8)

with windows of time, ``[t_0 + i W, t_0 + (i + 1) W)`` for ``W = window_us`` microseconds from the first event's
time ``t_0``, or of count, events ``i N .. (i + 1) N - 1`` for ``N = count`` (the last may be partial); each frame
is one ``np.bincount`` of its slice of the time-ordered events, when asked for. Files (:func:`read_events`):

* ``.npy``: a structured array with fields ``x``, ``y``, ``t``, ``p`` (``t`` in microseconds), memory-mapped,
  without pickles;
* ``.npz``: arrays ``x``, ``y``, ``t``, ``p``, or one structured array with those fields;
* ``.txt``: lines ``t x y p``, ``t`` in seconds (the RPG / ESIM data sets' ``events.txt``), ``#`` lines skipped.

Times must not decrease. The frame size is the model's reference image size when the caller knows it (an event
outside it is refused), else ``(max y + 1, max x + 1)`` of the recording.
"""

from __future__ import annotations

import warnings
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataError, InvalidValueError, VprError
from ..resources import MemoryNeed, check_memory, format_size, single_need

EVENT_SUFFIXES = frozenset({".npy", ".npz", ".txt"})
FIELDS = ("x", "y", "t", "p")
MAX_COUNT = 255  # counts saturate at the top of uint8
LIMIT = 2**62  # |t| in microseconds and x, y in pixels: beyond it a value is not a time or a pixel (int64 headroom)
MAX_FRAMES = 10_000_000  # frames of one recording: 2.8 hours at 1 ms windows; more is a wrong window or a bad clock


@dataclass(frozen=True)
class EventWindow:
    """How events are binned: ``window_us`` microseconds of time, or ``count`` events, per frame (one of them)."""

    window_us: int | None = None
    count: int | None = None

    def __post_init__(self) -> None:
        given = [v for v in (self.window_us, self.count) if v is not None]
        if len(given) != 1:
            raise InvalidValueError("an event recording is binned by --event-window-us or --event-count (one of them)")
        value = given[0]
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise InvalidValueError(f"--event-window-us / --event-count: expected a positive integer, got {value!r}")


@dataclass(frozen=True)
class Events:
    """Time-ordered events: int64 columns ``x``, ``y`` (pixels) and ``t`` (microseconds)."""

    x: np.ndarray
    y: np.ndarray
    t: np.ndarray


def _columns(path: Path) -> dict[str, np.ndarray]:
    suffix = path.suffix.lower()
    if suffix == ".txt":
        with warnings.catch_warnings():  # an empty file: "input contained no data" (refused below)
            warnings.simplefilter("ignore", UserWarning)
            table = np.loadtxt(path, dtype=np.float64, comments="#", ndmin=2)
        if table.size and table.shape[1] != 4:
            raise DataError(f"expected 4 columns 't x y p' per line, got {table.shape[1]}", path)
        table = table.reshape(-1, 4)  # no line: refused as no events below
        return {"t": table[:, 0] * 1e6, "x": table[:, 1], "y": table[:, 2], "p": table[:, 3]}
    if suffix == ".npz":
        with np.load(path, allow_pickle=False) as archive:
            if set(FIELDS) <= set(archive.files):
                return {name: archive[name] for name in FIELDS}
            if len(archive.files) == 1:
                return _fields(archive[archive.files[0]], path)
            raise DataError(f"expected arrays {', '.join(FIELDS)} or one structured array, got {archive.files}", path)
    return _fields(np.load(path, allow_pickle=False, mmap_mode="r"), path)


def _fields(array: np.ndarray, path: Path) -> dict[str, np.ndarray]:
    names = array.dtype.names or ()
    if array.ndim != 1 or not set(FIELDS) <= set(names):
        raise DataError(f"expected a 1-D structured array with fields {', '.join(FIELDS)}, got {array.dtype}", path)
    return {name: array[name] for name in FIELDS}


def _integers(values: np.ndarray, name: str, path: Path) -> np.ndarray:
    values = np.asarray(values)
    if values.dtype.kind in "iu":
        return values.astype(np.int64)
    if values.dtype.kind != "f" or not np.all(np.abs(values) < LIMIT):
        raise DataError(f"event field {name!r} must hold finite numbers below 2**62, got dtype {values.dtype}", path)
    rounded = np.rint(values)
    if name != "t" and not np.array_equal(rounded, values):
        raise DataError(f"event field {name!r} must hold whole pixel numbers", path)
    return rounded.astype(np.int64)


def load_need(path: Path) -> MemoryNeed:
    """Reading ``path``'s events, checked before reading: ``9 B`` bytes for ``B`` bytes of event data (the file,
    or an .npz's members uncompressed), as an event takes at least 4 bytes there (4 one-byte fields, or 8
    characters of text a line) and at most 36 in memory (x, y, t, their flat int64 pixel index, the parser's row)."""
    size = path.stat().st_size
    if path.suffix.lower() == ".npz" and zipfile.is_zipfile(path):
        with zipfile.ZipFile(path) as archive:
            size = sum(info.file_size for info in archive.infolist())
    return single_need(f"events of {format_size(size)} of data", 9 * size)


def read_events(path: str | Path) -> Events:
    """The events of ``path`` (``.npy``, ``.npz`` or ``.txt``, module docstring), checked; DataError naming it."""
    path = Path(path)
    try:
        check_memory(load_need(path), f"reading {path}", "a shorter recording would")
        columns = _columns(path)
    except VprError:  # over the memory limit (an InvalidValueError, also a ValueError), or a defect named already
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise DataError(f"cannot read events ({type(exc).__name__}: {exc})", path) from None
    sizes = {name: np.shape(columns[name]) for name in FIELDS}
    if len(set(sizes.values())) != 1 or len(sizes["t"]) != 1:
        raise DataError(f"the event fields must be 1-D and of one length, got {sizes}", path)
    x, y, t = (_integers(columns[name], name, path) for name in ("x", "y", "t"))
    for refused, problem in (
        (t.size == 0, "the recording holds no events"),
        (t.size and min(int(x.min()), int(y.min())) < 0, "event pixel coordinates must be >= 0"),
        (np.any(np.diff(t) < 0), "event times decrease: the events must be in time order"),
    ):
        if refused:
            raise DataError(problem, path)
    return Events(x, y, t)


def window_bounds(t: np.ndarray, window: EventWindow) -> Iterator[tuple[int, int]]:
    """(start, stop) per frame: frame ``i`` holds events ``start .. stop-1`` (module docstring); a time window
    with no event gives ``start == stop`` (an empty frame). One ``searchsorted`` per frame, as it is asked for."""
    n = t.size
    if window.count is not None:
        for start in range(0, n, window.count):
            yield start, min(start + window.count, n)
        return
    assert window.window_us is not None
    start, edge = 0, int(t[0])
    while start < n:
        edge += window.window_us
        stop = int(np.searchsorted(t, edge, side="left"))
        yield start, stop
        start = stop


def frame_count(t: np.ndarray, window: EventWindow) -> int:
    """How many frames the windows make: ``ceil(n / N)`` by count, ``floor((t_last - t_0) / W) + 1`` by time."""
    if window.count is not None:
        return -(-t.size // window.count)
    assert window.window_us is not None
    return (int(t[-1]) - int(t[0])) // window.window_us + 1


def bin_frames(events: Events, window: EventWindow, shape: tuple[int, int]) -> Iterator[np.ndarray]:
    """The uint8 count frames ``F_i`` (module docstring) of ``shape`` (height, width), one at a time."""
    height, width = shape
    flat = events.y * width + events.x
    for start, stop in window_bounds(events.t, window):
        counts = np.bincount(flat[start:stop], minlength=height * width)
        yield np.minimum(counts, MAX_COUNT).astype(np.uint8).reshape(height, width)


def event_frames(
    path: str | Path, window: EventWindow, shape: tuple[int, int] | None = None
) -> Iterator[tuple[str, np.ndarray]]:
    """The frames binned from the recording ``path``, named ``<file>#<index>``; read and checked now, so a bad
    file fails before the first frame. ``shape``: (height, width) of the sensor (default: the events' extent)."""
    path = Path(path)
    events = read_events(path)
    extent = (int(events.y.max()) + 1, int(events.x.max()) + 1)
    if shape is None:
        shape = extent
        need = single_need(f"event frame {shape[1]} x {shape[0]} (int64 counts)", 9 * shape[0] * shape[1])
        check_memory(need, f"binning {path}", "a recording of a smaller sensor would")
    elif extent[0] > shape[0] or extent[1] > shape[1]:
        raise DataError(
            f"events reach pixel (x={extent[1] - 1}, y={extent[0] - 1}), outside the model's "
            f"{shape[1]}x{shape[0]} frames: a recording of another sensor size is refused",
            path,
        )
    count = frame_count(events.t, window)
    if count > MAX_FRAMES:
        raise DataError(
            f"binning makes {count} frames (events over {int(events.t[-1]) - int(events.t[0])} us), more than "
            f"{MAX_FRAMES}: a wider --event-window-us or --event-count, or a recording without a clock jump, would do",
            path,
        )
    return ((f"{path.name}#{index}", frame) for index, frame in enumerate(bin_frames(events, window, shape)))
