"""Every command's stdout and output files on three small routes, normalised, as one JSON record.

The record of one commit is compared with another's (``tests/test_identity_outputs.py`` holds a recorded copy):
a refactor that keeps every feature leaves it unchanged. Timings and the scratch folder's path are masked;
JSON files are compared without their timing keys, other files byte for byte (sha256).

    python tools/identity_outputs.py --out record.json [--only lens,dev,demo]
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import os
import re
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
NORDLAND = SHARED / "nordland_64x32_summer_winter" / "places.csv"
LENS = SHARED / "lens_example_davis128"
#: JSON keys whose values are measured times or hosts (they change from run to run).
VOLATILE = re.compile(
    r"(seconds|_s$|^wall|elapsed|time|created|duration|host|latency|version|commit|python|platform)", re.I
)
#: The "platform" entry of a report's versions block in text (Markdown, or HTML-escaped): the machine, not the run.
PLATFORM = re.compile(r'("|&quot;)(platform)("|&quot;): ("|&quot;)[^"&]*("|&quot;)')
T = ["--threads", "2", "--quiet"]
DEV = ["--data", str(NORDLAND), "--places", "0:300"]


def routes() -> dict[str, list[list[str]]]:
    """The commands of each route, in order (later ones read what earlier ones wrote)."""
    lens = ["--data", str(LENS)]
    return {
        "lens": [
            ["train", *lens, "--reference", "example-reference", "--epochs", "4", "--seed", "1", "--out", "lens.npz"],
            [
                "evaluate",
                "lens.npz",
                *lens,
                "--query",
                "example-query",
                "--k",
                "1,3",
                "--baseline",
                "--predictions",
                "lens-predictions.csv",
            ],
            [
                "evaluate",
                "lens.npz",
                *lens,
                "--query",
                "example-query",
                "--k",
                "1,3",
                "--json",
                "--predictions",
                "lens-predictions.jsonl",
            ],
            [
                "localize",
                "lens.npz",
                *lens,
                "--calibrate",
                "example-query",
                "--k",
                "3",
                "--precision",
                "0.3",
                "--operating-point",
                "lens-op.json",
            ],
            ["localize", "lens.npz", "--frames", str(LENS / "example-query"), "--k", "3"],
            ["quantize", "lens.npz", "--bits", "4", "--out", "lens-models"],
            [
                "simulate",
                "lens-models/model_4bit_per-neuron_max.npz",
                *lens,
                "--query",
                "example-query",
                "--k",
                "1,3",
                "--json",
            ],
            [
                "verify",
                "lens.npz",
                *lens,
                "--query",
                "example-query",
                "--bits",
                "8,4",
                "--k",
                "1,3",
                "--targets",
                "none",
                "--report",
                "lens-verify",
            ],
        ],
        "dev": [
            [
                "train",
                *DEV,
                "--reference",
                "summer",
                "--preset",
                "lean",
                "--set",
                "train.epochs=4",
                "--seed",
                "1",
                "--out",
                "dev.npz",
            ],
            [
                "evaluate",
                "dev.npz",
                *DEV,
                "--query",
                "winter",
                "--k",
                "1,5",
                "--baseline",
                "--predictions",
                "dev-predictions.csv",
            ],
            ["evaluate", "dev.npz", *DEV, "--query", "winter", "--k", "1,5", "--json"],
            ["quantize", "dev.npz", "--bits", "8,4", "--out", "dev-models"],
            ["simulate", "dev-models/model_4bit_per-neuron_max.npz", *DEV, "--query", "winter", "--k", "1,5"],
            ["verify", "dev.npz", *DEV, "--query", "winter", "--bits", "8,4", "--k", "1,5", "--report", "dev-verify"],
            [
                "export",
                "dev-models/model_4bit_per-neuron_max.npz",
                "--to",
                "nir,loihi,onnx",
                "--out",
                "dev-deploy",
                "--check",
                *DEV,
                "--query",
                "winter",
            ],
            [
                "localize",
                "dev.npz",
                *DEV,
                "--calibrate",
                "winter",
                "--k",
                "5",
                "--precision",
                "0.9",
                "--operating-point",
                "dev-op.json",
            ],
        ],
        "demo": [["demo", "--out", "demo"]],
    }


def masked_text(text: str, work: Path) -> str:
    """stdout/stderr without the scratch path and the measured seconds (JSON: without its timing keys)."""
    text = re.sub(r"\d{4}-\d\d-\d\dT[\d:.]+(\+\d\d:\d\d)?", "DATE", text.replace(str(work), "WORK"))
    try:
        return json.dumps(masked_json(json.loads(text)), sort_keys=True, indent=0)
    except ValueError:
        pass
    try:
        lines = [json.loads(line) for line in text.splitlines() if line.strip()]
        return "\n".join(json.dumps(masked_json(v), sort_keys=True) for v in lines)
    except ValueError:
        pass
    text = re.sub(r"\d+(\.\d+)? ?(s|ms|min)\b", "N s", text)
    text = PLATFORM.sub(r"\1\2\3: \4MACHINE\5", text)  # a report's versions block names the kernel it ran on
    return re.sub(r"\d+(\.\d+)?/s\b", "N/s", text)


def masked_json(value: object) -> object:
    if isinstance(value, dict):
        return {k: masked_json(v) for k, v in value.items() if not VOLATILE.search(str(k))}
    if isinstance(value, list):
        return [masked_json(v) for v in value]
    return value


def file_digest(path: Path, work: Path) -> str:
    """sha256 of a file's normalised content: JSON without timings, text without the scratch path, else bytes."""
    data = path.read_bytes()
    if path.suffix in (".json", ".jsonl"):
        try:
            data = masked_text(data.decode(), work).encode()
        except ValueError:
            pass
    elif path.suffix in (".csv", ".md", ".txt", ".html", ".svg", ".nir"):
        data = masked_text(data.decode(errors="replace"), work).encode()
    return hashlib.sha256(data).hexdigest()


def run_route(commands: list[list[str]], work: Path) -> list[dict]:
    from vprsnn_export.cli import main

    out = []
    for command in commands:
        before = {p: p.stat().st_mtime_ns for p in work.rglob("*") if p.is_file()}
        stdout, stderr = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            try:
                code = main([*command, *T])
            except SystemExit as exit_:
                code = exit_.code
        written = sorted(p for p in work.rglob("*") if p.is_file() and before.get(p) != p.stat().st_mtime_ns)
        out.append(
            {
                "command": " ".join(command).replace(str(SHARED), "SHARED"),
                "exit": code,
                "stdout": masked_text(stdout.getvalue(), work),
                "stderr": masked_text(stderr.getvalue(), work),
                "files": {str(p.relative_to(work)): file_digest(p, work) for p in written},
            }
        )
        print(f"{code} {' '.join(command)[:100]}", file=sys.stderr)
    return out


def record(only: list[str]) -> dict:
    result = {}
    for name, commands in routes().items():
        if name not in only:
            continue
        with tempfile.TemporaryDirectory(prefix="identity-") as folder:
            work = Path(folder).resolve()
            cwd = os.getcwd()
            os.chdir(work)
            try:
                result[name] = run_route(commands, work)
                if os.environ.get("IDENTITY_KEEP"):  # keep the files to compare two records by hand
                    shutil.copytree(work, Path(os.environ["IDENTITY_KEEP"]) / name, dirs_exist_ok=True)
            finally:
                os.chdir(cwd)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--only", default="lens,dev,demo")
    args = parser.parse_args()
    Path(args.out).write_text(json.dumps(record(args.only.split(",")), indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
