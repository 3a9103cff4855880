"""Every committed docs/results page is what its experiment renders from the committed JSON beside it."""

from __future__ import annotations

import importlib
import json
from pathlib import Path

import pytest

from experiments.common import document

RESULTS = Path(__file__).resolve().parents[2] / "docs" / "results"
PAGES = sorted(p.stem for p in RESULTS.glob("*.json"))


def test_every_json_has_its_page():
    assert PAGES and all((RESULTS / f"{stem}.md").is_file() for stem in PAGES)


@pytest.mark.parametrize("stem", PAGES)
def test_page_matches_its_json(stem, tmp_path):
    results = json.loads((RESULTS / f"{stem}.json").read_text())
    name = results["experiment"]  # an experiment may write a page per data set (adaptation_<data folder>)
    module = importlib.import_module(f"experiments.{name}")
    page = document(name, module.DESCRIPTION, stem, results, module.render(results, tmp_path, stem))
    assert page == (RESULTS / f"{stem}.md").read_text(), (
        f"docs/results/{stem}.md differs from {stem}.json: regenerate it"
    )
