"""Event recordings (.npy, .npz, .txt of x, y, t, p) binned into count frames by a time or a count window."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vprsnn_export.data.events import EventWindow, bin_frames, read_events
from vprsnn_export.data.frames import iter_frames
from vprsnn_export.errors import DataError, InvalidValueError

FIELDS = [("x", "<u2"), ("y", "<u2"), ("t", "<i8"), ("p", "i1")]


def frames_to_events(frames: np.ndarray, window_us: int) -> np.ndarray:
    """A structured event array whose ``window_us`` time bins count back to ``frames`` (N, H, W): pixel value v
    of frame i is v events at time i * window_us + (pixel's row), inside frame i's window."""
    index, y, x = np.nonzero(frames)
    repeats = frames[index, y, x].astype(np.int64)
    events = np.zeros(int(repeats.sum()), FIELDS)
    events["x"], events["y"] = np.repeat(x, repeats), np.repeat(y, repeats)
    events["t"] = np.repeat(index * window_us + y, repeats)
    events["p"] = np.where(np.arange(events.size) % 2, 1, -1)
    return events[np.argsort(events["t"], kind="stable")]


@pytest.fixture
def frames() -> np.ndarray:
    counts = np.random.default_rng(0).integers(0, 4, (5, 6, 7)).astype(np.uint8)
    counts[:, 0, 0] = 1  # every window holds an event, the last included
    counts[:, -1, -1] = 2  # the events span the whole sensor
    return counts


def test_time_windows_count_the_events_back_into_the_frames(tmp_path, frames):
    events = frames_to_events(frames, 1000)
    np.save(tmp_path / "events.npy", events)
    np.savez(tmp_path / "fields.npz", **{name: events[name] for name, _ in FIELDS})
    text = "\n".join(f"{t / 1e6:.6f} {x} {y} {p}" for x, y, t, p in events.tolist())
    (tmp_path / "events.txt").write_text("# t x y p\n" + text + "\n")
    for name in ("events.npy", "fields.npz", "events.txt"):
        binned = list(iter_frames(tmp_path / name, events=EventWindow(window_us=1000)))
        assert [n for n, _ in binned] == [f"{name}#{i}" for i in range(5)]
        np.testing.assert_array_equal(np.stack([grey for _, grey in binned]), frames)


def saved(events: np.ndarray, path: Path):
    np.save(path, events)
    return read_events(path)


def test_count_windows_and_saturation(tmp_path, frames):
    events = frames_to_events(frames, 1000)
    counted = list(bin_frames(saved(events, tmp_path / "e.npy"), EventWindow(count=10), (6, 7)))
    assert len(counted) == -(-events.size // 10) and [int(f.sum()) for f in counted[:-1]] == [10] * (len(counted) - 1)
    assert int(counted[-1].sum()) == events.size - 10 * (len(counted) - 1)  # the last window is partial
    many = np.zeros(300, FIELDS)
    many["t"] = np.arange(300)
    (frame,) = bin_frames(saved(many, tmp_path / "many.npy"), EventWindow(window_us=1000), (1, 1))
    assert frame.dtype == np.uint8 and frame[0, 0] == 255  # counts saturate at 255


def test_bad_recordings_are_one_error(tmp_path, frames):
    events = frames_to_events(frames, 1000)
    path = tmp_path / "e.npy"
    np.save(path, events)
    with pytest.raises(DataError, match="binned into frames by --event-window-us or --event-count"):
        iter_frames(path)
    with pytest.raises(DataError, match=r"outside the model's 5x5 frames"):
        iter_frames(path, events=EventWindow(count=5), shape=(5, 5))
    backwards = events[::-1].copy()
    np.save(path, backwards)
    with pytest.raises(DataError, match="event times decrease"):
        iter_frames(path, events=EventWindow(count=5))
    np.save(path, np.zeros(3))
    with pytest.raises(DataError, match="structured array with fields x, y, t, p"):
        iter_frames(path, events=EventWindow(count=5))
    np.save(path, np.array([{"x": 1}], dtype=object))
    with pytest.raises(DataError, match="cannot read events"):  # never unpickled
        iter_frames(path, events=EventWindow(count=5))
    (tmp_path / "e.txt").write_text("0.1 1 2\n")
    with pytest.raises(DataError, match="expected 4 columns"):
        iter_frames(tmp_path / "e.txt", events=EventWindow(count=5))
    (tmp_path / "e.txt").write_text("0.1 1.5 2 1\n")
    with pytest.raises(DataError, match="whole pixel numbers"):
        iter_frames(tmp_path / "e.txt", events=EventWindow(count=5))
    for bad in ({}, {"window_us": 5, "count": 5}, {"count": 0}, {"window_us": True}):
        with pytest.raises(InvalidValueError):
            EventWindow(**bad)
    with pytest.raises(DataError, match="are for an event recording"):
        iter_frames(tmp_path, events=EventWindow(count=5))


def test_memory_is_checked_before_reading_or_binning(tmp_path, frames):
    from vprsnn_export.resources import set_memory_limit

    np.save(tmp_path / "e.npy", frames_to_events(frames, 1000))
    (tmp_path / "wide.txt").write_text("0 100000 100000 1\n")
    try:
        set_memory_limit("1K")
        with pytest.raises(InvalidValueError, match=r"reading .*e\.npy needs about .* over the limit of 1\.0 KiB"):
            iter_frames(tmp_path / "e.npy", events=EventWindow(count=5))
        set_memory_limit("1M")
        with pytest.raises(InvalidValueError, match=r"event frame 100001 x 100001"):
            iter_frames(tmp_path / "wide.txt", events=EventWindow(count=5))
    finally:
        set_memory_limit(None)


def test_a_gap_in_time_gives_empty_frames(tmp_path):
    (tmp_path / "gap.txt").write_text("0 1 1 1\n0.5 1 1 1\n")
    binned = [grey for _, grey in iter_frames(tmp_path / "gap.txt", events=EventWindow(window_us=100_000))]
    assert [int(f.sum()) for f in binned] == [1, 0, 0, 0, 0, 1]


def test_a_clock_jump_is_refused_before_binning_by_its_frame_count(tmp_path):
    """Issue 45: the last event 10^15 us after the others, binned at 1 us, would make 10^15 frames."""
    events = np.zeros(3, FIELDS)
    events["t"] = [0, 1, 10**15]
    np.save(tmp_path / "jump.npy", events)
    with pytest.raises(DataError, match="1000000000000001 frames"):
        next(iter_frames(tmp_path / "jump.npy", events=EventWindow(window_us=1)))
    assert len(list(iter_frames(tmp_path / "jump.npy", events=EventWindow(count=1)))) == 3
