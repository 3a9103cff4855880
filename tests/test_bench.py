"""Every benchmark script imports and parses its options, and one runs end to end on a tiny model
(the benches are not timed tests: the end-to-end run checks the table and the bench's own equality check)."""

from __future__ import annotations

import importlib.util
import os
import runpy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from vprsnn_export.export.model import save_fixed_point

BENCH_DIR = Path(__file__).resolve().parents[1] / "bench"
BENCH = sorted(BENCH_DIR.glob("*.py"))


@pytest.mark.parametrize("script", BENCH, ids=[p.name for p in BENCH])
def test_bench_script_starts(script, monkeypatch, capsys):
    """Each script imports and prints its usage (run in this process as ``python SCRIPT --help`` runs it:
    bench/ on the path, ``__main__``), without a subprocess that would import torch again."""
    threads = torch.get_num_threads()
    monkeypatch.syspath_prepend(str(BENCH_DIR))
    monkeypatch.setattr(sys, "argv", [str(script), "--help"])
    with pytest.raises(SystemExit) as done:
        runpy.run_path(str(script), run_name="__main__")
    assert done.value.code in (0, None)
    assert "usage" in capsys.readouterr().out
    assert torch.get_num_threads() == threads


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


@pytest.mark.skipif(
    importlib.util.find_spec("vprtempo") is None,
    reason="VPRTempo is not installed (the peers extra, see pyproject.toml): bench_peer.py leaves its row out",
)
def test_bench_peer_puts_vprtempo_beside_our_network(tmp_path, image_route):
    """bench_peer end to end on 10 synthetic places (VPRTempo at 28 x 28, one epoch): a row per method, the
    ratio lines, the bench's own checks (one query at a time and batched decide alike; the early rule run on
    prefixes gives the library's counts) and a second run that reads VPRTempo's trained state back."""
    data = image_route(tmp_path / "data", 10)
    state = tmp_path / "vprtempo.npz"
    options = ["--data", str(data), "--subset", str(data / "subset.csv"), "--repeats", "1", "--epochs", "1"]
    options += ["--peer-dims", "28,28", "--peer-state", str(state)]

    def run() -> dict[str, list[str]]:
        done = subprocess.run(
            [sys.executable, str(BENCH_DIR / "bench_peer.py"), *options],
            capture_output=True,
            text=True,
            timeout=600,
            env={**os.environ, "OMP_NUM_THREADS": "1"},
        )
        assert done.returncode == 0, done.stderr[-2000:]
        lines = done.stdout.splitlines()
        header = next(line for line in lines if line.startswith("method"))
        assert header.split()[1:3] == ["train", "s"] and header.endswith("events/query")
        table = lines[lines.index(header) + 1 :]
        rows = {line[:28].strip(): line[28:].split() for line in table if "/ vprtempo" not in line}
        assert sum("/ vprtempo:" in line for line in table) == 4  # ours / VPRTempo, per row of ours
        return rows

    rows = run()
    assert set(rows) == {"vprtempo", "ours T=300", "ours margin", "ours spikes 25", "ours T=150 (rate x2)", "cosine"}
    for name, cells in rows.items():
        assert float(cells[1]) > 0 and float(cells[2]) > 0, name  # ms per query, one at a time and batched
        assert 0 <= float(cells[3]) <= 100, name
        assert (cells[4] == "-") == (name == "vprtempo"), name
    assert float(rows["ours spikes 25"][4].replace(",", "")) < float(rows["ours T=300"][4].replace(",", ""))
    assert state.is_file()
    again = run()  # VPRTempo read back: its training seconds and accuracy as written
    assert again["vprtempo"][0] == rows["vprtempo"][0] and again["vprtempo"][3] == rows["vprtempo"][3]
