"""Start-up time of the command line: `--help`, `--version` and every command's `--help`, in fresh processes.

    python bench/bench_cli.py [--repeat 5] [--exe vprsnn-export] [--exe /other/checkout/.venv/bin/vprsnn-export]

Each invocation runs --repeat times as a new process (wall-clock, the median and the slowest, and the
median CPU time, user + system, which a busy machine changes less), so imports are counted the way a
user meets them. Give several --exe to compare two
installs (e.g. before and after a change). The machine may be shared: the load average is printed.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import time

from vprsnn_export.cli import command_names

INVOCATIONS = (["--help"], ["--version"], *([name, "--help"] for name in command_names()))


def timed(command: list[str]) -> tuple[float, float]:
    """(wall-clock seconds, CPU seconds) of one run of ``command``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    began = time.perf_counter()
    subprocess.run(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
    wall = time.perf_counter() - began
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--exe", action="append", help="the vprsnn-export executable(s) (default: the one on PATH)")
    args = parser.parse_args()
    executables = args.exe or [shutil.which("vprsnn-export") or "vprsnn-export"]
    print(f"load average {os.getloadavg()[0]:.1f}; {args.repeat} runs each, seconds")
    header = f"{'executable':<50} {'arguments':<18} {'median':>7} {'max':>7} {'cpu':>7}"
    print(header)
    print("-" * len(header))
    for exe in executables:
        for extra in INVOCATIONS:
            walls, cpus = zip(*(timed([exe, *extra]) for _ in range(args.repeat)), strict=True)
            median, slowest, cpu = statistics.median(walls), max(walls), statistics.median(cpus)
            print(f"{exe[-50:]:<50} {' '.join(extra):<18} {median:>7.2f} {slowest:>7.2f} {cpu:>7.2f}")


if __name__ == "__main__":
    main()
