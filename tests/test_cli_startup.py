"""`--help` and `--version` import no command module (no torch): the start-up bench/bench_cli.py times."""

from __future__ import annotations

import subprocess
import sys

import pytest

from vprsnn_export.cli import build_parser, command_names, summary

PROBE = """
import sys
from vprsnn_export.cli import main
code = main({argv!r})
heavy = sorted(m for m in ("torch", "numba", "onnx", "matplotlib", "vprsnn_export.commands.evaluate") if m in sys.modules)
print(code, heavy)
"""


@pytest.mark.parametrize("argv", [["--help"], ["--version"]])
def test_help_and_version_import_no_command(argv):
    done = subprocess.run([sys.executable, "-c", PROBE.format(argv=argv)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip().splitlines()[-1] == "0 []"


def test_every_command_is_listed_with_its_summary(capsys):
    names = command_names()
    assert {"evaluate", "localize", "verify", "demo"} <= set(names)
    assert summary("localize").startswith("a trained or deployed network over a stream of frames")
    full = build_parser()  # every command's real parser (the bad-input campaign's)
    assert full.parse_args(["localize", "m.npz", "--frames", "x"]).frames == "x"
    lazy = build_parser(["evaluate", "--help"])
    assert lazy.parse_args(["evaluate", "c.npz", "--query", "winter"]).query == "winter"
