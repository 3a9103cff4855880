"""docs/targets.md and docs/fixed-point.md name what exists and give the widths the files have."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

import vprsnn_export as vx
from vprsnn_export.config import Config, preset

DOCS = Path(__file__).resolve().parents[2] / "docs"
PAGES = ("targets.md", "fixed-point.md")
PACKAGES = ("runtime", "targets", "readout", "trainer", "data", "export", "io", "commands", "network")


def resolves(dotted: str) -> bool:
    """``dotted`` (package.module[.attribute...]) is an importable module of the project or an attribute of one."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            target = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        try:
            for name in parts[cut:]:
                target = getattr(target, name)
        except AttributeError:
            return False
        return True
    return False


def code_names(page: str) -> set[str]:
    """The dotted Python names in a page's code spans: ``vprsnn_export.X...``, ``vx.X``, ``package.module.name``."""
    spans = re.findall(r"`([^`]+)`", (DOCS / page).read_text())
    names = set()
    for span in spans:
        for name in re.findall(r"\b(?:vprsnn_export|vx|" + "|".join(PACKAGES) + r")(?:\.[A-Za-z_]\w*)+", span):
            if name.startswith("vx."):
                names.add("vprsnn_export." + name[3:])
            elif name.startswith("vprsnn_export."):
                names.add(name)
            elif name.count(".") >= 2:  # package.module.name: two segments are often a file or a config key
                names.add("vprsnn_export." + name)
    return names


@pytest.mark.parametrize("page", PAGES)
def test_every_python_name_the_page_gives_exists(page):
    names = code_names(page)
    assert "vprsnn_export.data.encoding.query_spikes" in names or page != "targets.md"
    missing = sorted(name for name in names if not resolves(name))
    assert missing == []
    assert not resolves("vprsnn_export.runtime.inference.query_spikes")  # the check can fail


def test_targets_page_gives_the_default_and_the_paper_input_widths():
    text = (DOCS / "targets.md").read_text()
    default, paper = Config().network.n_inputs, preset("paper").network.n_inputs
    steps = Config().encoder.timesteps
    assert (default, paper) == (1568, 784) and vx.Config().preprocess.channels == "dog_on_off"
    onnx_input = next(line for line in text.splitlines() if line.startswith("| input | `spikes`"))
    assert f"[{steps}, batch, {default}] for the default network" in onnx_input
    assert f"[{steps}, batch, {paper}] for the paper preset" in onnx_input
    assert f"**{default} inputs**" in text and "runtime.inference" not in text


def test_fixed_point_page_gives_the_default_networks_current_bounds():
    """docs/fixed-point.md §1 and §4: the largest 8-bit current of Config()'s width, and its float32-matmul bound."""
    text = " ".join((DOCS / "fixed-point.md").read_text().split())
    inputs = Config().network.n_inputs
    largest = inputs * (2**8 - 1)
    assert f"{largest:,} at the default {inputs} inputs, 8 bits" in text
    assert f"can reach {largest * 64:,} at 8 bits" in text and largest * 64 > 2**24
    assert f"a_j <= {largest:,} < 2^{largest.bit_length()}" in text
