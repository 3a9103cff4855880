"""The source fingerprint covers exactly the code a module runs: an edit there changes it, elsewhere not."""

from __future__ import annotations

import shutil
import sys

from experiments.sourcehash import PACKAGES, import_closure, source_fingerprint

ROOTS = ("experiments.common",)


def _copy(tmp_path):
    """The library and the lab copied side by side: {package: its copy}."""
    copies = {name: tmp_path / name for name in PACKAGES}
    for name, folder in PACKAGES.items():
        shutil.copytree(folder, copies[name], ignore=shutil.ignore_patterns("__pycache__"))
    return copies


def test_closure_is_what_importing_the_module_loads():
    import experiments.common  # noqa: F401  (the modules it loads are in sys.modules)

    loaded = {name for name in sys.modules if name.split(".")[0] in PACKAGES}
    closure = set(import_closure(ROOTS))
    assert closure <= loaded
    assert "vprsnn_export.trainer.stdp" in closure and "vprsnn_export.trainer.stdp_kernel" in closure
    assert {"experiments.common", "experiments.settings", "experiments.sourcehash"} <= closure
    assert not any(name.startswith(("vprsnn_export.commands", "vprsnn_export.runtime")) for name in closure)
    assert "experiments.plots" not in closure and "experiments.command" not in closure


def test_an_edit_to_the_training_code_changes_the_fingerprint(tmp_path):
    copies = _copy(tmp_path)
    before = source_fingerprint(ROOTS, copies)
    assert before == source_fingerprint(ROOTS, PACKAGES)
    with (copies["vprsnn_export"] / "trainer" / "stdp.py").open("a") as handle:
        handle.write("\n# an edit\n")
    assert source_fingerprint(ROOTS, copies) != before


def test_an_edit_to_the_lab_code_that_trains_changes_the_fingerprint(tmp_path):
    copies = _copy(tmp_path)
    before = source_fingerprint(ROOTS, copies)
    with (copies["experiments"] / "common.py").open("a") as handle:
        handle.write("\n# an edit\n")
    assert source_fingerprint(ROOTS, copies) != before


def test_an_edit_outside_the_closure_keeps_it(tmp_path):
    copies = _copy(tmp_path)
    before = source_fingerprint(ROOTS, copies)
    for package, outside in (
        ("vprsnn_export", "commands/experiment.py"),
        ("vprsnn_export", "runtime/evaluation.py"),
        ("experiments", "plots.py"),
        ("experiments", "command.py"),
    ):
        with (copies[package] / outside).open("a") as handle:
            handle.write("\n# an edit\n")
    assert source_fingerprint(ROOTS, copies) == before


def test_type_checking_imports_are_not_followed(tmp_path):
    root = tmp_path / "pkg"
    root.mkdir()
    (root / "__init__.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from . import b\n")
    (root / "a.py").write_text("from .c import f\n")
    (root / "b.py").write_text("x = 1\n")
    (root / "c.py").write_text("def f(): ...\n")
    assert sorted(import_closure(("pkg.a",), {"pkg": root})) == ["pkg", "pkg.a", "pkg.c"]
