"""Every command's outputs are those recorded before the readout's redesign (issue 42): stdout and every file
written, on the LENS example, a 300-place stretch of the dev route and the demo's route, timings masked
(``tools/identity_outputs.py``; the record is ``tests/data/identity_outputs.json``, recorded at 824b1db, its six
report files again from 2e0a365's code with the report's "platform" entry masked: it names the machine's kernel).

Re-recorded once since, for a change meant to move the last bits: the readout's products became sparse (issue
43: S^R, S'' and the counts as CSR, each row's sum in neuron order, in place of BLAS's blocked FMA sums). Seven
files and one command's stdout changed, only in confidences, by at most 2.4e-15 relative: every place, decision,
metric row and verdict the same (``IDENTITY_KEEP=DIR`` on both sides, then ``python tools/float_diff.py OLD NEW``).

Re-recorded a second time (2026-12-03) when the compiled kernels stopped following the machine's BLAS order (a
probe picked MKL's block of 192 or 384 inputs per shape and thread count, or the kernels' own order where none
matched) and now sum every current in increasing input order on every CPU. The record had stopped matching the
development machine (there the demo printed "no width is shown to hold" where the record said "8 bits holds", and
LENS scored 10 / 14 % at k = 1 where it said 8 / 13 %). On that machine this change, against the commit before it,
moved only LENS files: the trained weights' last bits (the checkpoint's hash), the predictions' confidences in
their last digits, and the localiser's per-frame decisions and threshold (its frames run one at a time).

Re-recorded a third time (2026-12-07) for the ONNX graph's ``modules`` input and the search rule written into
ONNX and network.json (issue 43): only the ``.onnx`` files, ``network.json``, ``export.json`` and the export
command's stdout (its statement) changed; each new entry was taken where the commit before and after it differed
on one machine, and the record's other entries were left as they were (on that machine, an AMD EPYC, the commit
before already differed from the record in the last digit of some confidences: two predictions files, two curves
and LENS's localize lines).

The tool runs in a process of its own with ``OMP_NUM_THREADS=2``, as the record was made: numpy's BLAS takes
its thread count when it loads (the readout's sums no longer use it, other products still may).

Slow: about 70 s at two threads. Re-record only for a change that is meant to move a figure, and say so."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RECORD = ROOT / "tests" / "data" / "identity_outputs.json"


@pytest.mark.slow
def test_every_commands_outputs_are_the_recorded_ones(tmp_path):
    recorded = json.loads(RECORD.read_text(encoding="utf-8"))
    out = tmp_path / "today.json"
    command = [
        sys.executable,
        str(ROOT / "tools" / "identity_outputs.py"),
        "--out",
        str(out),
        "--only",
        ",".join(recorded),
    ]
    done = subprocess.run(
        command, env={**os.environ, "OMP_NUM_THREADS": "2"}, capture_output=True, text=True, timeout=900
    )
    assert done.returncode == 0, done.stderr[-2000:]
    today = json.loads(out.read_text(encoding="utf-8"))
    for route, commands in recorded.items():
        assert [c["command"] for c in today[route]] == [c["command"] for c in commands]
        for was, now in zip(commands, today[route], strict=True):
            for part in ("exit", "stdout", "stderr", "files"):
                assert now[part] == was[part], f"{route}: {was['command'][:80]}: {part} differs"
