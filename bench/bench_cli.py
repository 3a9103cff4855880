"""Start-up time of the command line: `--help`, `--version` and a command's `--help`, in fresh processes.

    python bench/bench_cli.py [--repeat 5] [--exe vprsnn-export] [--exe /other/checkout/.venv/bin/vprsnn-export]

Each invocation runs --repeat times as a new process (wall-clock, the median and the slowest are
printed), so imports are counted the way a user meets them. Give several --exe to compare two
installs (e.g. before and after a change). The machine may be shared: the load average is printed.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import time

INVOCATIONS = (["--help"], ["--version"], ["evaluate", "--help"], ["localize", "--help"])


def timed(command: list[str]) -> float:
    began = time.perf_counter()
    subprocess.run(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
    return time.perf_counter() - began


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--exe", action="append", help="the vprsnn-export executable(s) (default: the one on PATH)")
    args = parser.parse_args()
    executables = args.exe or [shutil.which("vprsnn-export") or "vprsnn-export"]
    print(f"load average {os.getloadavg()[0]:.1f}; {args.repeat} runs each, seconds")
    header = f"{'executable':<50} {'arguments':<18} {'median':>7} {'max':>7}"
    print(header)
    print("-" * len(header))
    for exe in executables:
        for extra in INVOCATIONS:
            times = [timed([exe, *extra]) for _ in range(args.repeat)]
            print(f"{exe[-50:]:<50} {' '.join(extra):<18} {statistics.median(times):>7.2f} {max(times):>7.2f}")


if __name__ == "__main__":
    main()
