"""The README's tour of the commands parses as written: every subcommand and option it names exists."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from vprsnn_export.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]


def tour() -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    block = re.search(r"## The commands, on your own data\n\n```\n(.*?)```", text, re.S)
    assert block, "README has no tour of the commands"
    return [line.split("  #")[0].strip() for line in block.group(1).strip().splitlines()]


def as_argv(line: str) -> list[str]:
    """The line with every optional part given (brackets dropped), the first of each A|B choice, no ``...``."""
    words = shlex.split(line.replace("[", " ").replace("]", " ").replace("...", " "))
    assert words[0] == "vprsnn-export"
    return [word.split("|")[0] if "|" in word and not word.startswith("-") else word for word in words[1:]]


def test_the_tour_names_the_seven_commands_of_a_deployment():
    named = {as_argv(line)[0] for line in tour()}
    assert {"train", "evaluate", "quantize", "export", "verify", "localize", "report"} <= named
    assert len(tour()) <= 10


@pytest.mark.parametrize("line", tour())
def test_each_tour_line_parses(line):
    argv = as_argv(line)
    args = build_parser(argv).parse_args(argv)
    assert callable(args.handler)
