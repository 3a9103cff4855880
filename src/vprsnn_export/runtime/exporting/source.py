"""The model file read for export (:func:`load_source`), the integer model the integer targets get, every target written."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from vprsnn_export.errors import InvalidValueError, ModelFileError
from vprsnn_export.export.model import FORMAT as FIXED_FORMAT
from vprsnn_export.export.model import FixedPointModel, load_fixed_point
from vprsnn_export.export.quantize import QuantiseOptions
from vprsnn_export.io.checkpoint import FORMAT as CHECKPOINT_FORMAT
from vprsnn_export.io.checkpoint import Checkpoint, load_checkpoint
from vprsnn_export.io.fileio import parse_json, read_container, sha256_file
from vprsnn_export.targets.nir_target import WTA_INHIBITION
from vprsnn_export.targets.registry import TARGETS, WriteOptions

from ..deployment import deploy


@dataclass(frozen=True)
class ExportSource:
    """A model file read for export: a float checkpoint or a fixed-point model."""

    path: Path
    sha256: str
    network: Checkpoint | FixedPointModel  # what NIR exports and what the project's own simulator runs

    @classmethod
    def of(cls, network: Checkpoint | FixedPointModel, sha256: str, path: str | Path = "<in memory>") -> ExportSource:
        """A network held in memory (``sha256`` names it in the exported files' provenance)."""
        return cls(Path(path), sha256, network)

    @property
    def checkpoint(self) -> Checkpoint | None:
        return self.network if isinstance(self.network, Checkpoint) else None

    @property
    def fixed_point(self) -> FixedPointModel | None:
        return self.network if isinstance(self.network, FixedPointModel) else None

    @property
    def kind(self) -> str:
        return "float checkpoint" if self.checkpoint is not None else "fixed-point model"


MANIFEST_NAME = "export.json"  # a deploy folder's manifest: every file's sha256, written last by export
#: What reading a damaged export.json raises (unreadable, not UTF-8 or JSON, beyond parse_json's limits, another shape).
MANIFEST_ERRORS = (OSError, UnicodeDecodeError, InvalidValueError, KeyError, TypeError, AttributeError, ValueError)


def check_against_manifest(path: str | Path, digest: str | None = None) -> Path:
    """``path``, after checking it against the export.json beside it when that lists it: a file run from a deploy
    folder must be the one export wrote (its sha256). ModelFileError naming the file when it differs or the
    manifest cannot be read; a file with no export.json beside it, or one it does not list, is returned as it is.
    ``digest``: the file's sha256 when the caller has it already (it is read once)."""
    path = Path(path)
    manifest = path.parent / MANIFEST_NAME
    if not manifest.is_file() or not path.is_file():
        return path
    try:
        listed = [
            entry
            for entries in parse_json(manifest.read_bytes(), MANIFEST_NAME)["files"].values()
            for entry in entries
            if Path(str(entry["path"])).name == path.name
        ]
    except MANIFEST_ERRORS as exc:
        raise ModelFileError(f"corrupt {MANIFEST_NAME} beside the file ({str(exc)[:120]})", manifest) from None
    if listed and (digest or sha256_file(path)) not in {str(entry.get("sha256")) for entry in listed}:
        raise ModelFileError(
            f"differs from what export wrote ({MANIFEST_NAME}'s sha256): a changed or damaged file is not run", path
        )
    return path


def load_source(path: str | Path) -> ExportSource:
    """A checkpoint or a fixed-point model, chosen by the container's ``format`` field."""
    path = Path(path)
    digest = sha256_file(path) if path.is_file() else ""  # a missing file: read_container names it below
    check_against_manifest(path, digest)  # before the file is read: a damaged one is refused for what it is
    kind = read_container(path, "model")[0].get("format")
    if kind == CHECKPOINT_FORMAT:
        return ExportSource(path, digest, load_checkpoint(path))
    if kind == FIXED_FORMAT:
        return ExportSource(path, digest, load_fixed_point(path))
    raise ModelFileError(f"neither a checkpoint nor a fixed-point model (format {kind!r})", path)


def integer_model(source: ExportSource, bits: int | None, targets: Sequence[str]) -> FixedPointModel | None:
    """The fixed-point model the integer targets get, or None when none is asked for: a float checkpoint is
    quantised only when ``bits`` is given (per-neuron max-abs scales, the float calibration kept)."""
    if source.fixed_point is not None:
        if bits is not None:
            raise InvalidValueError("--quantize applies to float checkpoints; this is already a fixed-point model")
        return source.fixed_point
    wanted = [t for t in targets if TARGETS.get(t).integer_only]
    if not wanted or source.checkpoint is None:
        return None
    if bits is None:
        raise InvalidValueError(
            f"{' and '.join(wanted)} need a fixed-point model: run `vprsnn-export quantize CHECKPOINT --bits 8 "
            "--per-neuron --out DIR` and export the model it writes, add --quantize 8 here, or export with --to nir"
        )
    return deploy(source.checkpoint, source.sha256, bits, QuantiseOptions(calibration="float"))


def consumer_statements(
    source: ExportSource, model: FixedPointModel | None, targets: Sequence[str], wta_node: bool, inhibition: float
) -> dict[str, str]:
    """What each consumer of each written file computes, in one sentence or three (each target's ``statement``)."""
    notes = {
        entry.name: entry.statement(source.network, model, WriteOptions(source.sha256, inhibition, wta_node))
        for entry in TARGETS.values()
        if entry.name in targets and (model is not None or not entry.integer_only)
    }
    return {name: note for name, note in notes.items() if note is not None}


def export_all(
    source: ExportSource,
    model: FixedPointModel | None,
    targets: Sequence[str],
    out: Path,
    *,
    inhibition: float = WTA_INHIBITION,
    wta_node: bool = False,
) -> dict[str, list[Path]]:
    """Write each target into ``out`` in the registry's order: the source itself to a target that takes
    either (NIR), the fixed-point model to an integer-only one (ONNX, Loihi-style files).

    InvalidValueError for a target that is not registered, or an integer-only one without ``model``.
    """
    wanted = {TARGETS.get(name).name for name in targets}
    entries = [entry for entry in TARGETS.values() if entry.name in wanted]  # in the registry's order
    if model is None and (integer := [entry.name for entry in entries if entry.integer_only]):
        raise InvalidValueError(f"{' and '.join(integer)} need a fixed-point model")
    options = WriteOptions(source.sha256, inhibition, wta_node)
    written: dict[str, list[Path]] = {}
    for entry in entries:
        network = model if entry.integer_only and model is not None else source.network
        written[entry.name] = entry.write(network, out / entry.filename, options)
    return written
