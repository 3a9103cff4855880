"""The source fingerprint covers exactly the code a module runs: an edit there changes it, elsewhere not."""

from __future__ import annotations

import shutil
import sys

from vprsnn_export.experiments.sourcehash import PACKAGE_ROOT, import_closure, source_fingerprint

ROOTS = ("vprsnn_export.experiments.common",)


def _copy(tmp_path):
    root = tmp_path / "vprsnn_export"
    shutil.copytree(PACKAGE_ROOT, root, ignore=shutil.ignore_patterns("__pycache__"))
    return root


def test_closure_is_what_importing_the_module_loads():
    import vprsnn_export.experiments.common  # noqa: F401  (the modules it loads are in sys.modules)

    loaded = {name for name in sys.modules if name.split(".")[0] == "vprsnn_export"}
    closure = set(import_closure(ROOTS))
    assert closure <= loaded
    assert "vprsnn_export.trainer.stdp" in closure and "vprsnn_export.trainer.stdp_kernel" in closure
    assert not any(name.startswith(("vprsnn_export.commands", "vprsnn_export.runtime")) for name in closure)
    assert "vprsnn_export.experiments.plots" not in closure


def test_an_edit_to_the_training_code_changes_the_fingerprint(tmp_path):
    root = _copy(tmp_path)
    before = source_fingerprint(ROOTS, root)
    assert before == source_fingerprint(ROOTS, PACKAGE_ROOT)
    with (root / "trainer" / "stdp.py").open("a") as handle:
        handle.write("\n# an edit\n")
    assert source_fingerprint(ROOTS, root) != before


def test_an_edit_outside_the_closure_keeps_it(tmp_path):
    root = _copy(tmp_path)
    before = source_fingerprint(ROOTS, root)
    for outside in ("commands/experiment.py", "experiments/plots.py", "runtime/verify.py"):
        with (root / outside).open("a") as handle:
            handle.write("\n# an edit\n")
    assert source_fingerprint(ROOTS, root) == before


def test_type_checking_imports_are_not_followed(tmp_path):
    root = tmp_path / "pkg"
    root.mkdir()
    (root / "__init__.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from . import b\n")
    (root / "a.py").write_text("from .c import f\n")
    (root / "b.py").write_text("x = 1\n")
    (root / "c.py").write_text("def f(): ...\n")
    assert sorted(import_closure(("pkg.a",), root, "pkg")) == ["pkg", "pkg.a", "pkg.c"]
