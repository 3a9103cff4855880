"""Every command's outputs are those recorded before the readout's redesign (issue 42): stdout and every file
written, on the LENS example, a 300-place stretch of the dev route and the demo's route, timings masked
(``tools/identity_outputs.py``; the record is ``tests/data/identity_outputs.json``, recorded at 824b1db).

Slow: about 70 s at two threads. Re-record only for a change that is meant to move a figure, and say so."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RECORD = ROOT / "tests" / "data" / "identity_outputs.json"


def tool():
    spec = importlib.util.spec_from_file_location("identity_outputs", ROOT / "tools" / "identity_outputs.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_every_commands_outputs_are_the_recorded_ones(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    recorded = json.loads(RECORD.read_text(encoding="utf-8"))
    today = json.loads(json.dumps(tool().record(list(recorded))))
    for route, commands in recorded.items():
        assert [c["command"] for c in today[route]] == [c["command"] for c in commands]
        for was, now in zip(commands, today[route], strict=True):
            for part in ("exit", "stdout", "stderr", "files"):
                assert now[part] == was[part], f"{route}: {was['command'][:80]}: {part} differs"
