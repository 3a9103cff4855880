"""Every experiment's --quick size runs on the synthetic route and writes well-formed JSON, Markdown and plots."""

import json
import re

import pytest

from vprsnn_export.cli import main
from vprsnn_export.commands.experiment import experiment_modules

NAMES = sorted(experiment_modules())


@pytest.fixture(scope="module")
def out_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("results")


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("VPRSNN_CACHE", str(tmp_path_factory.getbasetemp() / "ckpt-cache"))


def test_every_paper_experiment_is_listed():
    assert {
        "assignment",
        "ablation",
        "state_isolation",
        "aggregation",
        "envelope",
        "scalability",
        "quantisation",
        "timing",
        "epochs",
    } <= set(NAMES)


@pytest.mark.parametrize("name", NAMES)
def test_quick_experiment_writes_json_markdown_and_plots(name, out_dir):
    assert main(["experiment", name, "--quick", "--out", str(out_dir), "--quiet"]) == 0
    results = json.loads((out_dir / f"{name}_quick.json").read_text())
    assert results["experiment"] == name
    assert results["provenance"]["settings"]["quick"] is True
    assert results["command"].startswith("vprsnn-export experiment")
    markdown = (out_dir / f"{name}_quick.md").read_text()
    assert markdown.startswith(f"# Experiment: {name}")
    assert re.search(r"\| *-?\d+(\.\d+)?", markdown), "the Markdown must hold a table of numbers"
    for image in re.findall(r"\]\(([^)]+\.png)\)", markdown):
        assert (out_dir / image).stat().st_size > 1000
    assert "nan" not in markdown.lower()


def test_unknown_experiment_is_a_clear_error(capsys):
    assert main(["experiment", "nope", "--quick"]) == 2
    assert "unknown experiment 'nope'" in capsys.readouterr().err
