"""The deployment targets' registry: how each is written, read back, checked and described.

One :class:`Target` per format. `export` writes the targets asked for (``--to``),
`verify` and `export --check` read every written file back and run it beside the
project's simulators (:mod:`runtime.conformance`), export.json states what each
consumer computes; all of them iterate :data:`TARGETS` in registration order (the
default order of ``--to``, ``--targets``, the written files and the checks). Adding a
target is a writer/reader module in this folder and one ``TARGETS.register`` line
(docs/architecture.md).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from vprsnn_export.errors import ModelFileError
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.registry import Registry
from vprsnn_export.targets.nir_semantics import WTA_INHIBITION

if TYPE_CHECKING:
    from vprsnn_export.network.runs import Backend

Network = Checkpoint | FixedPointModel
Loaded = TypeVar("Loaded")


@dataclass(frozen=True)
class WriteOptions:
    """How the targets are written: the source's sha256 (provenance), NIR's WTA node, and whether the files
    are written for the conformance checks (ONNX with its W+Prob head and raster outputs)."""

    source_sha256: str | None = None
    inhibition: float = WTA_INHIBITION
    wta_node: bool = False
    conformance: bool = False


@dataclass(frozen=True)
class Target:
    """One deployment target.

    ``write(network, path, options)`` writes ``path`` (= output folder / ``filename``) and
    returns the files; ``read(path)`` gives back a network that the project's simulators run
    (compared integer by integer with the one written) or a backend of its own (onnxruntime).
    ``integer_only``: it takes a fixed-point model only (a float checkpoint is quantised first).
    ``label`` names its checks, ``title`` the read-back network's backend; ``statement`` says what
    its consumers compute (export.json). ``reads_folder``: the reader takes the folder of the files.
    ``float_consumers``: the field's float simulators run its file too (the consumer gate and the consumers'
    measurements apply to it: NIR).
    """

    name: str
    title: str
    label: str
    integer_only: bool
    filename: str
    write: Callable[[Network, Path, WriteOptions], list[Path]]
    read: Callable[[Path], Network | Backend]
    statement: Callable[[Network, FixedPointModel | None, WriteOptions], str | None]
    reads_folder: bool = False
    float_consumers: bool = False

    def reader_path(self, files: Sequence[Path]) -> Path:
        return Path(files[0]).parent if self.reads_folder else Path(files[0])


def load_file(path: Path, kind: str, what: str, load: Callable[[Path], Loaded]) -> Loaded:
    """``load(path)``; "no such <kind> file" when absent, "not a readable <what>" when the loader raises anything."""
    if not path.is_file():
        raise ModelFileError(f"no such {kind} file", path)
    try:
        return load(path)
    except Exception as exc:  # whatever a third-party reader raises on a damaged file
        raise ModelFileError(
            f"not a readable {what} (truncated or corrupt: {type(exc).__name__}: {exc})", path
        ) from None


def integer(network: Network, target: str) -> FixedPointModel:
    """The fixed-point model an integer target writes (TypeError for a float checkpoint: callers quantise first)."""
    if not isinstance(network, FixedPointModel):
        raise TypeError(f"{target} writes a fixed-point model, not a float checkpoint")
    return network


# The writers, readers and statements load their modules when called: the registry (listed by every
# command's --help) imports neither torch nor onnx.


def lazy(dotted: str) -> Callable[..., Any]:
    """``targets.<module>.<name>`` (``dotted`` = "module.name"), imported when the returned function is called."""
    module, name = dotted.split(".")

    def call(*args: Any) -> Any:
        return getattr(importlib.import_module(f"vprsnn_export.targets.{module}"), name)(*args)

    return call


def _write_nir(network: Network, path: Path, options: WriteOptions) -> list[Path]:
    from vprsnn_export.targets.nir_target import write_nir

    sha = options.source_sha256
    return [write_nir(network, path, source_sha256=sha, wta_inhibition=options.inhibition, wta_node=options.wta_node)]


def _write_onnx(network: Network, path: Path, options: WriteOptions) -> list[Path]:
    from vprsnn_export.targets.onnx_target import write_onnx

    return [write_onnx(integer(network, "onnx"), path, with_wprob=True, with_raster=options.conformance)]


def _write_loihi(network: Network, path: Path, options: WriteOptions) -> list[Path]:
    from vprsnn_export.targets.loihi_target import write_loihi

    return list(write_loihi(integer(network, "loihi"), path, source_sha256=options.source_sha256).values())


TARGETS: Registry[Target] = Registry("target")
for name, title, label, integer_only, filename, write, reader, reads_folder in (
    ("nir", "NIR", "NIR read back", False, "model.nir", _write_nir, "nir_read.read_nir", False),
    ("onnx", "ONNX", "ONNX (onnxruntime)", True, "model.onnx", _write_onnx, "onnx_session.OnnxBackend", False),
    ("loihi", "Loihi", "Loihi read back", True, "loihi", _write_loihi, "loihi_target.read_loihi_model", True),
):
    statement = lazy(f"statements.{name}_statement")
    consumers = name == "nir"  # snnTorch, SpikingJelly, nirtorch... read NIR (targets/nir_consumers.py)
    TARGETS.register(
        Target(name, title, label, integer_only, filename, write, lazy(reader), statement, reads_folder, consumers)
    )


__all__ = ["TARGETS", "Network", "Target", "WriteOptions", "integer"]
