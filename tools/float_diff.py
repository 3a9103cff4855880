"""Two folders of command outputs compared number by number: which files differ, and whether only in floats.

For every file that differs byte for byte, JSON / JSON lines / CSV are parsed and compared value by value: a
pair of floats may differ by at most ``--rtol`` (relative); anything else (a place, a decision, a key, a count)
must be equal. Prints one line per differing file and exits 1 when any difference is more than a float's.

    python tools/float_diff.py OLD_FOLDER NEW_FOLDER [--rtol 1e-12]
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from identity_outputs import masked_json, masked_text  # noqa: E402  (the record's masks: timings, dates, paths)


def parsed(path: Path) -> object:
    """The file's values, without the keys and text the identity record masks (timings, dates)."""
    text = path.read_text(encoding="utf-8")
    if path.suffix == ".json":
        return masked_json(json.loads(text))
    if path.suffix == ".jsonl":
        return [masked_json(json.loads(line)) for line in text.splitlines() if line.strip()]
    if path.suffix == ".csv":
        return [[number(cell) for cell in row] for row in csv.reader(text.splitlines())]
    return masked_text(text, path.parent).splitlines()


def number(cell: str) -> object:
    try:
        return int(cell)
    except ValueError:
        try:
            return float(cell)
        except ValueError:
            return cell


def differences(a: object, b: object, rtol: float, where: str = "") -> tuple[int, float, list[str]]:
    """(floats that differ, their largest relative difference, the other differences' paths)."""
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            return 0, 0.0, [f"{where}: keys"]
        parts = [differences(a[k], b[k], rtol, f"{where}/{k}") for k in a]
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return 0, 0.0, [f"{where}: length"]
        parts = [differences(x, y, rtol, f"{where}[{i}]") for i, (x, y) in enumerate(zip(a, b, strict=True))]
    elif isinstance(a, float) and isinstance(b, float) and a != b:
        relative = abs(a - b) / max(abs(a), abs(b))
        return 1, relative, [] if relative <= rtol else [f"{where}: {a!r} != {b!r}"]
    else:
        return 0, 0.0, [] if a == b else [f"{where}: {str(a)[:40]!r} != {str(b)[:40]!r}"]
    return sum(p[0] for p in parts), max((p[1] for p in parts), default=0.0), [x for p in parts for x in p[2]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old", type=Path)
    parser.add_argument("new", type=Path)
    parser.add_argument("--rtol", type=float, default=1e-12)
    args = parser.parse_args()
    worse = False
    for path in sorted(p for p in args.old.rglob("*") if p.is_file()):
        other = args.new / path.relative_to(args.old)
        if not other.is_file() or path.read_bytes() == other.read_bytes():
            continue
        if path.suffix not in (".json", ".jsonl", ".csv", ".md", ".html", ".txt"):
            print(f"{path.relative_to(args.old)}: differs (not compared value by value)")
            continue
        floats, largest, other_differences = differences(parsed(path), parsed(other), args.rtol)
        worse |= bool(other_differences)
        print(f"{path.relative_to(args.old)}: {floats} floats differ (largest relative {largest:.1e}); "
              f"{len(other_differences)} other differences {other_differences[:3]}")  # fmt: skip
    sys.exit(1 if worse else 0)


if __name__ == "__main__":
    main()
