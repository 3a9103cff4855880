"""`vprsnn-export experiment NAME`: regenerate one of the paper's tables or figures as JSON + Markdown + plots.

The experiments are the repository's lab (``experiments/``), found beside the source or under the working folder.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

from ..errors import VprError

LAB = "experiments"  # the lab's package, at the repository root
ENTRY = f"{LAB}.command"  # its module with add_arguments(parser) and run(args)
HELP = "run one of the paper's experiments (JSON, Markdown, plots)"
MISSING = (
    "the experiments live in the vprsnn-export repository, not in the installed package: run "
    "`vprsnn-export experiment NAME` from a checkout's root (git clone, then pip install -e .)"
)


def lab_folder() -> Path | None:
    """The lab's folder: beside this package's source in a checkout, else under the working folder, else None."""
    for folder in (Path(__file__).resolve().parents[3] / LAB, Path.cwd() / LAB):
        if (folder / "command.py").is_file() and (folder / "__init__.py").is_file():
            return folder
    return None


def load_lab() -> ModuleType | None:
    """The lab's command module (:data:`ENTRY`) from :func:`lab_folder` or an already imported lab; None: no lab."""
    loaded = sys.modules.get(LAB)
    if loaded is None:
        folder = lab_folder()
        if folder is None:
            return None
        spec = importlib.util.spec_from_file_location(
            LAB, folder / "__init__.py", submodule_search_locations=[str(folder)]
        )
        assert spec is not None and spec.loader is not None  # a .py file: the source loader always serves it
        loaded = sys.modules[LAB] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(loaded)
    elif not (Path(loaded.__file__ or "").parent / "command.py").is_file():
        return None  # another package of that name
    return importlib.import_module(ENTRY)


def register(subparsers: argparse._SubParsersAction) -> None:
    lab = load_lab()
    if lab is None:  # an installed package: every invocation (--help too: no word is an option) is :func:`missing`
        parser = subparsers.add_parser("experiment", help=HELP, add_help=False, prefix_chars="\0")
        parser.add_argument("words", nargs="*")
        parser.set_defaults(handler=missing)
        return
    parser = subparsers.add_parser("experiment", help=HELP)
    lab.add_arguments(parser)


def missing(args: argparse.Namespace) -> int:
    raise VprError(MISSING)
