"""vprsnn-export: STDP place-recognition SNNs from training to fixed-point deployment.

``import vprsnn_export as vx`` gives the public API (:mod:`vprsnn_export.api`, listed in
``__all__``). Its names load on first use, so importing one submodule (the command line,
a test) does not import onnx, nir and matplotlib.
"""

from __future__ import annotations

import importlib
import importlib.util
from typing import TYPE_CHECKING, Any

from .version import __version__ as __version__

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
