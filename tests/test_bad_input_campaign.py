"""The bad-input campaign of issue 12 (tools/bad_input_campaign.py), run whole: about 15 minutes on one core.

Every bad input must stop with one line ``error: ...`` and exit 2 (no traceback, no usage block or
warning, no silent acceptance, no hang), and every legal extreme must run.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

TOOL = Path(__file__).resolve().parents[1] / "tools" / "bad_input_campaign.py"


@pytest.mark.slow
def test_bad_input_campaign(tmp_path):
    done = subprocess.run(
        [sys.executable, str(TOOL), "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=40 * 60,
        stdin=subprocess.DEVNULL,
    )
    assert (tmp_path / "bad_inputs.json").is_file(), done.stderr[-3000:]
    cases = json.loads((tmp_path / "bad_inputs.json").read_text(encoding="utf-8"))["cases"]
    bad = [c for c in cases if not c["legal"]]
    legal = [c for c in cases if c["legal"]]
    assert len(bad) >= 300 and len(legal) >= 80

    def ids(group: list[dict], klass: str) -> list[str]:
        return [f"{c['id']}: {c['last_line']}" for c in group if c["class"] == klass]

    assert ids(bad, "traceback") == []
    assert ids(bad, "multi-line") == []
    assert ids(bad, "accepted") == []
    assert ids(bad, "timeout") == []
    assert [f"{c['id']} ({c['class']}): {c['last_line']}" for c in legal if c["class"] != "ran"] == []
    assert done.returncode == (0 if all(c["class"] in ("clean", "ran") for c in cases) else 1)
