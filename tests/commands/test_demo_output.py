"""docs/verify.md's demo block is today's demo output (slow: the real demo, about a minute at two threads)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from vprsnn_export.cli import main

ROOT = Path(__file__).resolve().parents[2]


def masked(lines: list[str]) -> list[str]:
    """The output with what changes from run to run replaced: seconds, and the report's absolute path."""
    out = []
    for line in lines:
        line = re.sub(r"\(\d+ s\)", "(N s)", line)
        line = re.sub(r"\d+ s in all", "N s in all", line)
        line = re.sub(r"^report: .*/demo/report/report.html$", "report: demo/report/report.html", line)
        out.append(line)
    return out


def documented() -> list[str]:
    text = (ROOT / "docs" / "verify.md").read_text(encoding="utf-8")
    block = re.search(r"## The demo\n.*?```\n(.*?)```", text, re.S)
    assert block, "docs/verify.md has no demo block"
    return block.group(1).rstrip("\n").splitlines()


@pytest.mark.slow
def test_the_documented_demo_output_is_todays(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["demo", "--out", "demo", "--threads", "2", "--quiet"]) == 0
    printed = capsys.readouterr().out.rstrip("\n").splitlines()
    assert masked(printed) == masked(documented())


def test_the_readme_shows_the_documented_conclusion():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    block = re.search(r"## What the demo shows.*?```\n(.*?)```", text, re.S)
    assert block, "README has no demo block"
    shown = block.group(1).rstrip("\n").splitlines()
    assert shown == documented()[: len(shown)] and shown[0].startswith("Conclusion: ")
