"""The public API: every name in ``__all__`` resolves, and the documented example runs the whole chain."""

from __future__ import annotations

import json
import runpy
import subprocess
import sys
from pathlib import Path

import pytest

import vprsnn_export as vx
from vprsnn_export import api

EXAMPLE = Path(__file__).resolve().parents[1] / "docs" / "examples" / "quickstart.py"


def test_every_public_name_resolves_and_has_a_docstring():
    assert set(vx.__all__) == set(api.__all__)
    for name in api.__all__:
        value = getattr(vx, name)
        if callable(value):
            assert value.__doc__, f"{name} has no docstring"


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        vx.nope  # noqa: B018


def test_importing_the_package_does_not_load_the_heavy_targets():
    code = "import sys, vprsnn_export; print(json.dumps(sorted(m for m in sys.modules if m in ('onnx', 'nir', 'matplotlib'))))"
    out = subprocess.run([sys.executable, "-c", "import json; " + code], capture_output=True, text=True, check=True)
    assert json.loads(out.stdout) == []


def test_the_quickstart_example_runs_the_whole_chain(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    runpy.run_path(str(EXAMPLE), run_name="__main__")
    printed = capsys.readouterr().out
    counts = json.loads(printed.splitlines()[1].replace("'", '"'))
    assert set(counts) == {"integer simulator", "reference stepper", "onnxruntime"}
    assert len(set(counts.values())) == 1  # three backends, the same spikes
    assert "verdict: PASS" in printed
    for name in ("deploy/model.nir", "deploy/model.onnx", "deploy/export.json", "report/report.html"):
        assert (tmp_path / name).is_file(), name
    code = [line for line in EXAMPLE.read_text().split("import vprsnn_export as vx", 1)[1].splitlines() if line.strip()]
    assert len(code) <= 20  # notebook-sized
