"""A fingerprint of the source that computes a result: the first-party files a module imports, transitively.

A cache keyed by it (experiments' trained checkpoints) is never reused after that code changed. It
belongs to the experiments (their cache key), not to the library they run. First-party are the library
(``vprsnn_export``) and this lab (``experiments``), each read from the folder it is imported from.
"""

from __future__ import annotations

import ast
import hashlib
from collections.abc import Mapping
from functools import lru_cache
from pathlib import Path

import vprsnn_export

#: First-party packages and their folders: the library, wherever it is imported from, and this lab.
PACKAGES: Mapping[str, Path] = {
    "vprsnn_export": Path(vprsnn_export.__file__).resolve().parent,
    "experiments": Path(__file__).resolve().parent,
}


def module_file(name: str, packages: Mapping[str, Path] = PACKAGES) -> Path | None:
    """The file of the first-party module ``name`` (``package.a.b`` -> ``root/a/b.py`` or ``root/a/b/__init__.py``,
    ``root = packages[package]``)."""
    parts = name.split(".")
    if parts[0] not in packages:
        return None
    folder = packages[parts[0]].joinpath(*parts[1:])
    candidates = [folder / "__init__.py"] + ([folder.with_suffix(".py")] if len(parts) > 1 else [])
    return next((path for path in candidates if path.is_file()), None)


def first_party_imports(name: str, path: Path, packages: Mapping[str, Path] = PACKAGES) -> set[str]:
    """Every module of ``packages`` the source of ``name`` (at ``path``) imports, anywhere in the file except
    under ``if TYPE_CHECKING:`` (annotations run no code). ``from a import b`` names both ``a`` and ``a.b``
    (``b`` may be a module); names that are not modules are dropped by :func:`import_closure`."""
    source = path.read_text(encoding="utf-8")
    return set(_imports_in_source(name, path.name == "__init__.py", source, frozenset(packages)))


@lru_cache(maxsize=1024)
def _imports_in_source(name: str, is_package: bool, source: str, packages: frozenset[str]) -> frozenset[str]:
    """:func:`first_party_imports` of a source text (cached by the text itself, so an edit is seen)."""
    base = name.split(".") if is_package else name.split(".")[:-1]
    found: set[str] = set()
    pending: list[ast.AST] = [ast.parse(source)]
    while pending:
        node = pending.pop()
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            pending.extend(node.orelse)
            continue
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            parent = base[: len(base) - (node.level - 1)] if node.level else []
            target = ".".join(parent + ([node.module] if node.module else []))
            found.add(target)
            found.update(f"{target}.{alias.name}" for alias in node.names)
        pending.extend(ast.iter_child_nodes(node))
    return frozenset(module for module in found if module.split(".")[0] in packages)


def import_closure(roots: tuple[str, ...], packages: Mapping[str, Path] = PACKAGES) -> dict[str, Path]:
    """The first-party modules ``roots`` import, transitively, with their parent packages: name -> file."""
    files: dict[str, Path] = {}
    pending = list(roots)
    while pending:
        parts = pending.pop().split(".")
        for depth in range(1, len(parts) + 1):
            name = ".".join(parts[:depth])
            path = None if name in files else module_file(name, packages)
            if path is not None:
                files[name] = path
                pending.extend(first_party_imports(name, path, packages))
    return files


def source_fingerprint(roots: tuple[str, ...], packages: Mapping[str, Path] = PACKAGES) -> str:
    """sha256 over the names and bytes of :func:`import_closure` of ``roots``, in name order:
    ``H = sha256(name_1 NUL bytes_1 NUL ... name_n NUL bytes_n NUL)``."""
    digest = hashlib.sha256()
    for name, path in sorted(import_closure(roots, packages).items()):
        digest.update(name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()
