"""The folders depend on each other in one direction only (docs/architecture.md).

Every ``import`` of a ``vprsnn_export`` module, at module top or inside a function, must
point to the same layer or an earlier one; first-party imports sit at module top, except in
the modules the command line's ``--help`` imports (:data:`LOADS_ON_USE`), which load the library
when a command runs (tests/test_cli_startup.py); and no modules import each other in a circle.
"""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Layers in dependency order: a module may import from its own layer or an earlier one.
LAYERS = ("core", "trainer", "export", "targets", "runtime", "experiments", "api", "commands")


def package_root() -> Path:
    """The folder that holds ``vprsnn_export``, read from pyproject.toml (the one place that names it)."""
    with (ROOT / "pyproject.toml").open("rb") as handle:
        where = tomllib.load(handle)["tool"]["setuptools"]["packages"]["find"]["where"]
    return ROOT / where[0] / "vprsnn_export"


#: Modules whose first-party imports may sit inside functions: the commands (their parsers are built
#: without torch; the library loads in the handler) and the targets' registry (its writers and readers).
LOADS_ON_USE = ("vprsnn_export.commands.", "vprsnn_export.targets.registry", "vprsnn_export.runtime.backends")


def layer_of(module: str) -> str:
    """The layer of a dotted module name inside the package."""
    parts = module.split(".")
    if module in ("vprsnn_export", "vprsnn_export.api"):
        return "api"
    if len(parts) > 1 and parts[1] in ("trainer", "export", "targets", "runtime", "experiments"):
        return parts[1]
    if len(parts) > 1 and parts[1] in ("commands", "cli", "__main__"):
        return "commands"
    return "core"


def package_modules() -> dict[str, Path]:
    """Every module of the package with its file."""
    modules: dict[str, Path] = {}
    folder = package_root()
    for path in sorted(folder.rglob("*.py")):
        relative = path.relative_to(folder).with_suffix("")
        parts = [p for p in relative.parts if p != "__init__"]
        modules[".".join(["vprsnn_export", *parts])] = path
    return modules


def imports_of(module: str, path: Path) -> list[tuple[str, int, bool]]:
    """(imported module, line, at module top) for every first-party import of a file."""
    tree = ast.parse(path.read_text(), filename=str(path))
    is_package = path.name == "__init__.py"
    found: list[tuple[str, int, bool]] = []
    top_level = {id(node) for node in tree.body}
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                base = base if is_package else base[:-1]
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            names = [target]
            if node.module is None or target in ("vprsnn_export",):
                names = [
                    f"{target}.{alias.name}" if f"{target}.{alias.name}" in MODULES else target for alias in node.names
                ]
        at_top = id(node) in top_level or _inside_type_checking(tree, node)
        found += [(name, node.lineno, at_top) for name in names if name.split(".")[0] == "vprsnn_export"]
    return found


def _inside_type_checking(tree: ast.Module, node: ast.AST) -> bool:
    for block in tree.body:
        if isinstance(block, ast.If) and "TYPE_CHECKING" in ast.unparse(block.test):
            if any(child is node for child in ast.walk(block)):
                return True
    return False


MODULES = package_modules()


def test_the_package_has_the_expected_modules():
    assert "vprsnn_export.config" in MODULES and "vprsnn_export.targets.intsim" in MODULES
    assert {layer_of(m) for m in MODULES} == set(LAYERS)


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_import_points_to_a_later_layer(module: str):
    rank = LAYERS.index(layer_of(module))
    back_edges = [
        f"line {line}: {target} ({layer_of(target)})"
        for target, line, _ in imports_of(module, MODULES[module])
        if LAYERS.index(layer_of(target)) > rank
    ]
    assert not back_edges, f"{module} ({layer_of(module)}) imports from a later layer: {back_edges}"


@pytest.mark.parametrize("module", sorted(m for m in MODULES if not m.startswith(LOADS_ON_USE)))
def test_first_party_imports_are_at_module_top(module: str):
    inside = [f"line {line}: {target}" for target, line, top in imports_of(module, MODULES[module]) if not top]
    assert not inside, f"{module} imports inside functions: {inside}"


def test_a_back_edge_is_detected(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("from vprsnn_export.runtime.verify import verify_checkpoint\n")
    assert [(t, top) for t, _, top in imports_of("vprsnn_export.trainer.bad", bad)] == [
        ("vprsnn_export.runtime.verify", True)
    ]
    assert LAYERS.index(layer_of("vprsnn_export.runtime.verify")) > LAYERS.index("trainer")


def import_graph() -> dict[str, set[str]]:
    """module -> the first-party modules it imports (at top, under TYPE_CHECKING or inside a function)."""
    return {m: {t for t, _, _ in imports_of(m, path) if t in MODULES and t != m} for m, path in MODULES.items()}


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The groups of modules that import each other in a circle (strongly connected components of more than
    one module, Tarjan's algorithm), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for target in sorted(graph.get(node, ())):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            group = []
            while True:
                member = stack.pop()
                group.append(member)
                if member == node:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return sorted(found)


def test_no_modules_import_each_other_in_a_circle():
    assert not circles(import_graph()), f"import circles among first-party modules: {circles(import_graph())}"


def test_a_circle_is_detected(tmp_path):
    assert circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": {"e"}}) == [["a", "b", "c"]]
    hidden = tmp_path / "hidden.py"  # an import only type checkers follow still closes a circle
    hidden.write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from vprsnn_export.config import Config\n"
    )
    graph = {**import_graph(), "vprsnn_export.data.preprocess": {"vprsnn_export.config"}}
    assert ("vprsnn_export.config", 3, True) in imports_of("vprsnn_export.data.hidden", hidden)
    assert ["vprsnn_export.config", "vprsnn_export.data.preprocess"] in circles(graph)
