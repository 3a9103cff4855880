"""Text from outside is parsed strictly: ASCII decimal numbers only, bounded JSON, one-line stdout errors."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from vprsnn_export import threads
from vprsnn_export.commands._common import integer, parse_int_list, parse_value
from vprsnn_export.commands.export import parse_shape
from vprsnn_export.data.dataset import parse_places, parse_synthetic
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.network.modules import MAX_MODULES, module_regions
from vprsnn_export.targets import onnx_target

EXOTIC = ["²", "٣", "３", "1_0", "⁵"]


@pytest.mark.parametrize("digit", EXOTIC)
def test_non_ascii_digits_are_not_numbers(digit, monkeypatch):
    with pytest.raises(InvalidValueError):
        parse_synthetic(f"synthetic:{digit}")
    with pytest.raises(InvalidValueError):
        parse_shape(f"{digit}x400x1568")
    with pytest.raises(InvalidValueError):
        parse_places(f"{digit}:3")
    with pytest.raises(InvalidValueError):
        parse_int_list(f"1,{digit}", "--k")
    with pytest.raises(ValueError):
        integer(digit)
    monkeypatch.setenv("OMP_NUM_THREADS", digit)
    assert threads.default_threads() == threads.DEFAULT_THREADS


def test_ascii_numbers_still_parse():
    assert parse_synthetic("synthetic:12") == 12
    assert parse_shape("2x400x784") == (2, 400, 784)
    assert parse_places("3:4:2") == (3, 4, 2)
    assert parse_int_list("1,3", "--k") == (1, 3)
    assert integer("-4") == -4


@pytest.mark.parametrize("raw", ["[" * 5000 + "]" * 5000, "9" * 5001])
def test_hostile_json_options_are_one_error(raw):
    with pytest.raises(InvalidValueError, match="--set/--grid value"):
        parse_value(raw)
    assert parse_value("[1, 2]") == [1, 2] and parse_value("dog") == "dog"


def test_too_many_modules_is_a_stated_limit():
    with pytest.raises(InvalidValueError, match="train.module_size"):
        module_regions(MAX_MODULES * 4, 2)
    assert np.array_equal(module_regions(5, 2), [[0, 2], [2, 4], [4, 5]])


def test_onnx_refuses_an_accumulator_that_would_wrap(monkeypatch, tiny_model):
    model = tiny_model  # current sums of 4 inputs x 3
    onnx_target.check_exportable(model)
    monkeypatch.setattr(onnx_target, "INT32_MAX", 11)
    with pytest.raises(InvalidValueError, match="int32 accumulator"):
        onnx_target.check_exportable(model)


def run_cli(*args: str, stdout: int | None) -> subprocess.CompletedProcess:
    code = "import sys; from vprsnn_export.__main__ import run; sys.argv[0] = 'vprsnn-export'; run()"
    return subprocess.run(
        [sys.executable, "-c", code, *args], stdout=stdout, stderr=subprocess.PIPE, text=True, timeout=120
    )


def test_a_full_stdout_is_one_line_and_a_closed_pipe_is_quiet():
    with open("/dev/full", "w") as full:
        done = run_cli("experiment", "list", stdout=full.fileno())
    assert done.returncode == 1
    assert done.stderr.strip().splitlines() == ["error: cannot write the standard output (No space left on device)"]
    reader = subprocess.Popen(["head", "-c", "1"], stdin=subprocess.PIPE, stdout=subprocess.DEVNULL)
    assert reader.stdin is not None
    reader.stdin.close()  # the reader is gone before anything is written
    reader.wait()
    read_end = subprocess.Popen(["true"], stdin=subprocess.PIPE)
    read_end.wait()
    assert read_end.stdin is not None
    done = run_cli("experiment", "list", stdout=read_end.stdin.fileno())
    assert done.returncode == 141 and "Traceback" not in done.stderr


@pytest.mark.parametrize("option", ["--help", "--version"])
def test_help_that_cannot_be_written_is_not_a_success(option):
    """argparse swallows OSError while printing help; the parser does not, so the text is not lost with exit 0."""
    with open("/dev/full", "w") as full:
        done = run_cli(option, stdout=full.fileno())
    assert done.returncode == 1
    assert done.stderr.strip().splitlines() == ["error: cannot write the standard output (No space left on device)"]
