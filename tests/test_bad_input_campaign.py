"""The bad-input campaign of issues 12 and 24 (tools/bad_input_campaign.py), run whole: CLI, API and faults.

Every bad input must stop with one line ``error: ...`` and exit 2 (no traceback, no usage block or
warning, no silent acceptance, no hang), every legal extreme must run; every public function with a
bad argument raises the project's error (or accepts a legal value), nothing it writes fails to load;
a kill while writing, a full or closed standard output and a Ctrl-C at start-up are handled.
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
    sections = {c["command"] for c in cases}
    assert {"(api)", "(faults)", "train"} <= sections
    assert sum(c["command"] == "(api)" for c in cases) >= 1000

    def ids(group: list[dict], klass: str) -> list[str]:
        return [f"{c['id']}: {c['last_line']}" for c in group if c["class"] == klass]

    assert ids(bad, "traceback") == []
    assert ids(bad, "multi-line") == []
    assert ids(bad, "accepted") == []
    assert ids(bad, "write-then-refuse") == []
    assert ids(bad, "crash") == []
    assert ids(bad, "timeout") == []
    assert [f"{c['id']}: {c['note']}" for c in bad if c["class"] == "other"] == []
    assert [f"{c['id']} ({c['class']}): {c['last_line']}" for c in legal if c["class"] != "ran"] == []
    assert done.returncode == (0 if all(c["class"] in ("clean", "ran") for c in cases) else 1)


def test_a_case_refused_for_another_reason_or_a_wrong_output_is_a_finding(tmp_path):
    """``Case.says`` and ``Case.check`` (issue 31): a clean refusal whose line lacks the expected reason, or a
    legal run whose output fails its check, is "other"; otherwise the class stands."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("bad_input_campaign", TOOL)
    assert spec is not None and spec.loader is not None
    tool = importlib.util.module_from_spec(spec)
    sys.modules.setdefault(spec.name, tool)  # its dataclasses look their module up
    spec.loader.exec_module(sys.modules[spec.name])
    tool = sys.modules[spec.name]
    says = tool.bad("x", "experiment", says="experiments score query frame j")
    assert (
        tool.expected(says, "clean", ["error: experiments score query frame j as ..."], tmp_path, tmp_path)[0]
        == "clean"
    )
    klass, note = tool.expected(says, "clean", ["error: no such place manifest"], tmp_path, tmp_path)
    assert klass == "other" and "refused for another reason" in note
    checked = tool.legal("y", "evaluate", check="predictions-truth-offset-3")
    assert tool.expected(checked, "ran", [], tmp_path, tmp_path) == ("other", "ran, but no p.jsonl was written")
    rows = [{"query": q, "truth": [q + 3], "place_id": 4, "correct": q == 1} for q in range(3)]
    (tmp_path / "p.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    assert tool.expected(checked, "ran", [], tmp_path, tmp_path) == ("ran", "")
    (tmp_path / "p.jsonl").write_text(json.dumps({**rows[0], "truth": 0}) + "\n")  # the frame index: wrong
    assert tool.expected(checked, "ran", [], tmp_path, tmp_path)[0] == "other"
