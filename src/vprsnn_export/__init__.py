"""vprsnn-export: STDP place-recognition SNNs from training to fixed-point deployment.

``import vprsnn_export as vx`` gives the public API (:mod:`vprsnn_export.api`), its names loaded on first use.
"""

from __future__ import annotations

import sys

from .startup import install_guard, started_as_command

if started_as_command(sys.argv[0] if sys.argv else "", getattr(sys, "orig_argv", ())):
    install_guard()  # first: a Ctrl-C while the command loads is one line and exit 130 (startup.py)

import importlib  # noqa: E402  (after the guard above)
import importlib.util  # noqa: E402
from typing import TYPE_CHECKING, Any  # noqa: E402

from .version import __version__ as __version__  # noqa: E402

if TYPE_CHECKING:
    from .api import *  # noqa: F403

_API = "vprsnn_export.api"


def __getattr__(name: str) -> Any:
    if name != "__all__" and (name.startswith("_") or importlib.util.find_spec(f"{__name__}.{name}") is not None):
        raise AttributeError(name)  # a submodule (``from . import commands``) loads itself, not the whole API
    api = importlib.import_module(_API)
    if name == "__all__":  # `from vprsnn_export import *`
        return list(api.__all__)
    if name in api.__all__:
        return getattr(api, name)
    raise AttributeError(f"module 'vprsnn_export' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(importlib.import_module(_API).__all__))
