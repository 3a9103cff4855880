"""Every benchmark script imports and parses its options, and one runs end to end on a tiny model
(the benches are not timed tests: the end-to-end run checks the table and the bench's own equality check)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vprsnn_export.export.model import save_fixed_point

BENCH_DIR = Path(__file__).resolve().parents[1] / "bench"
BENCH = sorted(BENCH_DIR.glob("*.py"))


@pytest.mark.parametrize("script", BENCH, ids=[p.name for p in BENCH])
def test_bench_script_starts(script):
    done = subprocess.run([sys.executable, str(script), "--help"], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "usage" in done.stdout


def test_bench_onnx_prints_its_table_and_onnxruntime_agrees_with_the_simulator(make_model, tmp_path):
    """One benchmark run end to end on a tiny model: the table has a row per backend, and the
    counts onnxruntime computes are the integer simulator's (the bench's own check)."""
    model = save_fixed_point(tmp_path / "model.npz", make_model(np.random.default_rng(0)))
    script = BENCH_DIR / "bench_onnx.py"
    options = ["--queries", "4", "--repeat", "1", "--threads", "1", "--torch-threads", "1"]
    done = subprocess.run(
        [sys.executable, str(script), str(model), *options],
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.splitlines()
    header = next(line for line in lines if line.split()[:1] == ["backend"])
    assert header.split()[:4] == ["backend", "bits", "threads", "queries"] and header.endswith("counts == intsim")
    rows = {line.split()[0]: line.split() for line in lines if line.split()[:1] in (["intsim"], ["onnxruntime"])}
    assert set(rows) == {"intsim", "onnxruntime"}
    onnx = rows["onnxruntime"]
    assert onnx[1:5] == ["8", "1", "4", "20"]  # bits, threads, queries, T of the model written above
    assert float(onnx[5]) > 0 and onnx[-1] == "yes"
