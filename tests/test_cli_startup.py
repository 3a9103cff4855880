"""`--help`, `--version` and every command's `--help` import no torch (nor numba, onnx, nir, matplotlib, OpenCV): the
start-up bench/bench_cli.py times. The library loads when a command runs."""

from __future__ import annotations

import subprocess
import sys

import pytest

from vprsnn_export.cli import build_parser, command_names, summary

HEAVY = ("torch", "numba", "onnx", "nir", "matplotlib", "cv2")
PROBE = """
import sys
HEAVY = {heavy!r}
from vprsnn_export.cli import main
code = main({argv!r})
heavy = sorted(m for m in HEAVY + ("vprsnn_export.commands.evaluate",) if m in sys.modules)
print(code, heavy)
"""


@pytest.mark.parametrize("argv", [["--help"], ["--version"]])
def test_help_and_version_import_no_command(argv):
    done = subprocess.run(
        [sys.executable, "-c", PROBE.format(argv=argv, heavy=HEAVY)], capture_output=True, text=True, timeout=120
    )
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


EVERY_HELP = """
import contextlib, io, sys
from vprsnn_export.cli import build_parser, command_names, main
HEAVY = {heavy!r}
for name in command_names():
    build_parser([name])
    with contextlib.redirect_stdout(io.StringIO()) as text:
        code = main([name, "--help"])
    assert code == 0 and "usage: vprsnn-export " + name in text.getvalue(), (name, code)
    loaded = sorted(m for m in HEAVY if m in sys.modules)
    assert not loaded, f"{{name}} --help imported {{loaded}}"
print("ok", len(command_names()))
"""


def test_every_command_help_imports_no_torch():
    """Each command's parser is built from modules that do not import torch: its --help prints without it."""
    done = subprocess.run(
        [sys.executable, "-c", EVERY_HELP.format(heavy=HEAVY)], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["ok", str(len(command_names()))]


def test_the_probe_sees_torch_when_a_command_module_imports_it():
    """The check above can fail: a module that imports torch at its top is seen."""
    probe = "import sys; import vprsnn_export.device; print('torch' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert done.stdout.strip() == "True", done.stderr[-2000:]
