"""The Python 3.10 venv in which the slow tests run Lava (lava-nc 0.10) and lava-dl's netx (lava-dl 0.6).

Built on first use at ``~/.cache/vprsnn-export/lava-venv`` (override with VPRSNN_LAVA_VENV) from
pyenv's 3.10.13 or ``python3.10`` on PATH; each fixture installs what it needs from PyPI and
skips, with the reason, when no Python 3.10 exists or the install fails.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
from pathlib import Path

import pytest

LAVA_VENV = Path(os.environ.get("VPRSNN_LAVA_VENV", Path.home() / ".cache/vprsnn-export/lava-venv"))
PYTHON310 = [Path.home() / ".pyenv/versions/3.10.13/bin/python", shutil.which("python3.10")]
LAVA_NC = "lava-nc==0.10.*"
LAVA_DL = "lava-dl==0.6.0"  # pulls torch 2.3 (a CUDA build, about 3 GB, runs on the CPU here)


def venv_python(probe: str, requirement: str) -> Path:
    """The venv's interpreter once ``import probe`` works in it, creating the venv and installing ``requirement``:
    one process at a time (an exclusive lock beside the venv), so that two xdist workers never install into it
    at once (the second saw a half-installed torch: ``cannot import name 'nccl'``)."""
    LAVA_VENV.parent.mkdir(parents=True, exist_ok=True)
    with open(LAVA_VENV.parent / f"{LAVA_VENV.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        return _built_python(probe, requirement)


def _built_python(probe: str, requirement: str) -> Path:
    python = LAVA_VENV / "bin" / "python"
    if python.exists() and subprocess.run([python, "-c", f"import {probe}"], capture_output=True).returncode == 0:
        return python
    steps = [[str(python), "-m", "pip", "install", "-q", requirement]]
    if not python.exists():
        base = next((Path(p) for p in PYTHON310 if p and Path(p).exists()), None)
        if base is None:
            pytest.skip("Lava needs Python 3.10 and none was found (pyenv 3.10.13 or python3.10 on PATH)")
        steps.insert(0, [str(base), "-m", "venv", str(LAVA_VENV)])
    for step in steps:
        done = subprocess.run(step, capture_output=True, text=True, timeout=3600)
        if done.returncode != 0:
            pytest.skip(f"could not build the Lava venv ({' '.join(step[-2:])}): {done.stderr.strip()[-400:]}")
    return python


@pytest.fixture(scope="session")
def lava_python() -> Path:
    """The Lava venv's interpreter with lava-nc 0.10."""
    return venv_python("lava.proc.lif.process", LAVA_NC)


@pytest.fixture(scope="session")
def netx_python(lava_python: Path) -> Path:
    """The same venv with lava-dl 0.6 (netx) added."""
    return venv_python("lava.lib.dl.netx", LAVA_DL)
