"""`vprsnn-export experiment` is a thin command of the package that loads the repository's lab: found beside the
package's source in a checkout or under the working folder; without it, one line and exit 2."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import experiments
import vprsnn_export
from vprsnn_export.commands import experiment as thin

ROOT = Path(__file__).resolve().parents[2]


def test_the_lab_is_found_beside_the_package_source_and_is_the_one_imported():
    assert thin.lab_folder() == ROOT / "experiments"
    lab = thin.load_lab()
    assert lab is not None and lab.__name__ == "experiments.command"
    assert sys.modules["experiments"] is experiments  # one copy of the lab, whichever way it was imported


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """The package alone, as a wheel installs it (no repository around it)."""
    site = tmp_path_factory.mktemp("site")
    shutil.copytree(
        Path(vprsnn_export.__file__).parent, site / "vprsnn_export", ignore=shutil.ignore_patterns("__pycache__")
    )
    return site


def run_installed(site: Path, cwd: Path, *argv: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "vprsnn_export", "experiment", *argv],
        cwd=cwd,
        env={"PATH": "/usr/bin:/bin", "PYTHONPATH": str(site), "OMP_NUM_THREADS": "1"},
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.mark.parametrize("argv", [["list"], ["--help"], ["route", "--quick", "--threads", "1"], []])
def test_without_the_repository_it_is_one_line_and_exit_2(installed, tmp_path, argv):
    done = run_installed(installed, tmp_path, *argv)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.splitlines() == [f"error: {thin.MISSING}"]


def test_an_installed_package_finds_the_lab_under_the_working_folder(installed):
    done = run_installed(installed, ROOT, "list")
    assert done.returncode == 0, done.stderr[-2000:]
    names = [line.split()[0] for line in done.stdout.splitlines()]
    assert "route" in names and "cost" in names and "common" not in names and "command" not in names
