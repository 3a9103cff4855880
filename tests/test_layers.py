"""The folders depend on each other in one direction only (docs/architecture.md).

Every ``import`` of a ``vprsnn_export`` module, at module top or inside a function, must
point to the same layer or an earlier one; first-party imports sit at module top, except in
the modules the command line's ``--help`` imports (:data:`LOADS_ON_USE`), which load the library
when a command runs (tests/test_cli_startup.py); and no modules import each other in a circle.
The lab (the repository's ``experiments/``, not installed) may import any layer of the package; nothing
under src/ imports the lab (the ``experiment`` command loads it by name from a checkout).
"""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Layers in dependency order: a module may import from its own layer or an earlier one. The lab comes last:
#: it may import every layer, and an import of it from the package is a back-edge.
LAYERS = ("core", "trainer", "export", "targets", "runtime", "api", "commands", "lab")

with (ROOT / "pyproject.toml").open("rb") as _handle:
    _TOOL = tomllib.load(_handle)["tool"]

#: The lab's package, a folder of the repository root (pyproject's [tool.vprsnn-export], read also by tools/typecheck).
LAB = _TOOL["vprsnn-export"]["lab"]
FIRST_PARTY = ("vprsnn_export", LAB)


def package_root() -> Path:
    """The folder that holds ``vprsnn_export``, read from pyproject.toml (the one place that names it)."""
    return ROOT / _TOOL["setuptools"]["packages"]["find"]["where"][0] / "vprsnn_export"


#: Modules whose first-party imports may sit inside functions: the commands (their parsers are built
#: without torch; the library loads in the handler) and the targets' registry (its writers and readers).
#: The lab's command module is one of them (the experiments load when one runs).
LOADS_ON_USE = (
    "vprsnn_export.commands.",
    "vprsnn_export.targets.registry",
    "vprsnn_export.runtime.backends",
    f"{LAB}.command",
)


def layer_of(module: str) -> str:
    """The layer of a dotted module name inside the package, or "lab"."""
    parts = module.split(".")
    if parts[0] == LAB:
        return "lab"
    if module in ("vprsnn_export", "vprsnn_export.api"):
        return "api"
    if len(parts) > 1 and parts[1] in ("trainer", "export", "targets", "runtime"):
        return parts[1]
    if len(parts) > 1 and parts[1] in ("commands", "cli", "__main__"):
        return "commands"
    return "core"


def package_modules() -> dict[str, Path]:
    """Every module of the package and of the lab with its file."""
    modules: dict[str, Path] = {}
    for package, folder in (("vprsnn_export", package_root()), (LAB, ROOT / LAB)):
        for path in sorted(folder.rglob("*.py")):
            relative = path.relative_to(folder).with_suffix("")
            parts = [p for p in relative.parts if p != "__init__"]
            modules[".".join([package, *parts])] = path
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
        found += [(name, node.lineno, at_top) for name in names if name.split(".")[0] in FIRST_PARTY]
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
    assert f"{LAB}.common" in MODULES and f"{LAB}.sourcehash" in MODULES
    assert {layer_of(m) for m in MODULES} == set(LAYERS)


def test_the_lab_is_outside_the_installed_package():
    """The lab is a folder of the repository, not under the package root, and pyproject installs only the package."""
    assert not (package_root() / LAB).exists() and (ROOT / LAB / "__init__.py").is_file()
    assert _TOOL["setuptools"]["packages"]["find"]["include"] == ["vprsnn_export*"]


def test_nothing_under_src_imports_the_lab():
    """No file under src/ (every one a module of the package) imports the lab: at top, inside a function or
    for type checkers."""
    assert set(package_root().parent.rglob("*.py")) <= set(MODULES.values())
    found = [
        f"{MODULES[module].relative_to(ROOT)} line {line}: {target}"
        for module in MODULES
        if layer_of(module) != "lab"
        for target, line, _ in imports_of(module, MODULES[module])
        if layer_of(target) == "lab"
    ]
    assert not found, f"the package imports the lab: {found}"


def test_an_import_of_the_lab_is_detected(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text(f"def f():\n    from {LAB}.common import document\n")
    assert [(t, layer_of(t)) for t, _, _ in imports_of("vprsnn_export.commands.bad", bad)] == [(f"{LAB}.common", "lab")]


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
