"""Reading cost per frame of each `localize --frames` source: folder, ROS 2 bag, ROS 1 bag, event recording.

    OMP_NUM_THREADS=1 python bench/bench_streams.py [--frames 200] [--size 64x32] [--events-per-pixel 4]

What ``iter_frames`` costs before the localiser sees a frame (``latency_ms`` in localize's output starts at
the decoded frame): the wall time to take every frame from the source, divided by the frames. RANDOM
greyscale frames of --size (uint8) written as PNGs, as mono8 sensor_msgs/Image messages of a ROS 2 bag
(sqlite3) and a ROS 1 bag, and as an event recording (.npy, about --events-per-pixel events per pixel
and frame, binned back by a time window). Median of 5 passes; the machine may be shared (load printed).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from vprsnn_export.data.events import EventWindow
from vprsnn_export.data.frames import iter_frames

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "core" / "data"))
from test_bags import write_bag  # noqa: E402
from test_events import frames_to_events  # noqa: E402


def per_frame_ms(make, frames: int, passes: int = 5) -> float:
    times = []
    for _ in range(passes):
        began = time.perf_counter()
        count = sum(1 for _ in make())
        times.append(1000 * (time.perf_counter() - began) / count)
        assert count == frames, count
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--size", default="64x32", help="WIDTHxHEIGHT")
    parser.add_argument("--events-per-pixel", type=int, default=4)
    args = parser.parse_args()
    width, height = map(int, args.size.split("x"))
    rng = np.random.default_rng(0)
    grey = rng.integers(0, 256, (args.frames, height, width), dtype=np.uint8)
    counts = rng.poisson(args.events_per_pixel, (args.frames, height, width)).astype(np.uint8)
    counts[:, 0, 0] = np.maximum(counts[:, 0, 0], 1)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "frames"
        folder.mkdir()
        for index, image in enumerate(grey):
            cv2.imwrite(str(folder / f"f{index}.png"), image)
        ros2 = write_bag(Path(tmp) / "ros2", {"/cam": [("mono8", g) for g in grey]})
        ros1 = write_bag(Path(tmp) / "run.bag", {"/cam": [("mono8", g) for g in grey]}, ros1=True)
        np.save(Path(tmp) / "events.npy", frames_to_events(counts, 1000))
        window = EventWindow(window_us=1000)
        print(f"{args.frames} frames of {width} x {height}; load average {os.getloadavg()[0]:.1f}")
        print("| source | ms/frame |\n|---|---|")
        for name, make in (
            ("folder of PNGs", lambda: iter_frames(folder)),
            ("ROS 2 bag (sqlite3, mono8)", lambda: iter_frames(ros2)),
            ("ROS 1 bag (mono8)", lambda: iter_frames(ros1)),
            (f"events .npy ({int(counts.sum())} events)", lambda: iter_frames(Path(tmp) / "events.npy", events=window)),
        ):
            print(f"| {name} | {per_frame_ms(make, args.frames):.3f} |")


if __name__ == "__main__":
    main()
