"""The implementations table (docs/fixed-point.md §5.1, the contract's docstring) names tests that exist."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import vprsnn_export.export.model as contract

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = re.compile(r"(tests/[\w/]+\.py)?::(\w+)|(tests/[\w/]+\.py)")


def _references(text: str) -> list[tuple[str, str | None]]:
    """(test file, test function or None) of every reference; ``::name`` alone belongs to the last file named."""
    found: list[tuple[str, str | None]] = []
    last = ""
    for match in REFERENCE.finditer(text):
        if match.group(3):
            last = match.group(3)
            found.append((last, None))
        else:
            last = match.group(1) or last
            found.append((last, match.group(2)))
    return found


def _section(text: str) -> str:
    start = text.index("### 5.1 Every implementation of the step")
    return text[start : text.index("\nFloat fidelity:", start)]


def test_every_test_the_tables_name_exists():
    doc = _section((ROOT / "docs" / "fixed-point.md").read_text())
    docstring = contract.__doc__ or ""
    for text in (doc, docstring):
        references = _references(text)
        assert len(references) >= 10
        for file, name in references:
            path = ROOT / file
            assert path.is_file(), file
            if name is not None:
                functions = {n.name for n in ast.walk(ast.parse(path.read_text())) if isinstance(n, ast.FunctionDef)}
                assert name in functions, f"{file}::{name}"


def test_the_tables_list_the_same_implementations():
    doc = _section((ROOT / "docs" / "fixed-point.md").read_text())
    for module in (
        "dynamics",
        "dynamics_kernel.float_run",
        "intsim_kernel.integer_run",
        "stdp_kernel.stdp_window",
        "intsim",
    ):
        assert module in doc and module in (contract.__doc__ or "")
    for module in ("reference_stepper", "onnx_target", "nir_target", "nir_consumers", "loihi_target"):
        assert module in doc and module in (contract.__doc__ or "")
