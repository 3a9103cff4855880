"""The README's "Your own route" example runs as written, on the LENS example beside the repository."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LENS = ROOT.parent / "shared/data/lens_example_davis128"


def example_lines() -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    block = re.search(r"## Your own route.*?```sh\n(.*?)```", text, re.S)
    assert block, "README has no 'Your own route' shell block"
    return block.group(1).strip().splitlines()


def test_the_example_is_five_lines_of_the_project_commands():
    lines = example_lines()
    assert len(lines) == 5 and lines[0].startswith("D=")
    assert all(line.startswith("vprsnn-export ") for line in lines[1:])


@pytest.mark.slow
@pytest.mark.skipif(not LENS.is_dir(), reason="the LENS example is not beside the repository")
def test_the_example_runs_as_written(tmp_path):
    bin_dir = Path(sys.executable).parent
    env = {**os.environ, "D": str(LENS), "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}", "OMP_NUM_THREADS": "1"}
    script = "set -euo pipefail\n" + "\n".join(example_lines()) + "\n"
    done = subprocess.run(["bash", "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    assert (tmp_path / "lens.npz").is_file() and (tmp_path / "lens.operating-point.json").is_file()
    predictions = (tmp_path / "lens-predictions.csv").read_text(encoding="utf-8").splitlines()
    assert len(predictions) > 100  # a header and every query's decisions
    decisions = [json.loads(line) for line in (tmp_path / "decisions.jsonl").read_text().splitlines()]
    assert len(decisions) == 100 and {"place_id", "confidence", "accepted"} <= set(decisions[0])
