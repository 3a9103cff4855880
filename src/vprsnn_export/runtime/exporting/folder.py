"""The deploy folder: written as a whole with its export.json (:func:`export_and_check`), read back (:func:`read_export`)."""

from __future__ import annotations

import json
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import torch

from vprsnn_export.errors import InvalidValueError, ModelFileError
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.io.fileio import (
    OutputError,
    atomic_write_text,
    check_output_folder,
    parse_json,
    publish_folder,
    sha256_file,
    staging_folder,
)
from vprsnn_export.io.serial import JsonDataclass, json_options
from vprsnn_export.targets.loihi_budget import deployment_cost
from vprsnn_export.targets.nir_target import WTA_INHIBITION

from .checks import ExportChecks, check_exports
from .source import MANIFEST_ERRORS, MANIFEST_NAME, ExportSource, consumer_statements, export_all


@dataclass(frozen=True)
class WrittenFile(JsonDataclass):
    path: Path
    sha256: str


@dataclass(frozen=True)
class ExportResult(JsonDataclass):
    """What `export` wrote (export.json): the folder, the model, every file with its hash, the consumers, the checks."""

    folder: Path
    model: str
    model_sha256: str
    kind: str
    files: Mapping[str, tuple[WrittenFile, ...]]
    consumers: Mapping[str, str]
    checks: ExportChecks | None = field(default=None, metadata=json_options(omit="none"))
    # per query: steps, events, the chip estimates (targets.loihi_budget)
    cost: Mapping[str, Any] | None = field(default=None, metadata=json_options(omit="none"))

    @property
    def passed(self) -> bool:
        return self.checks is None or self.checks.passed

    def written(self, target: str) -> Path:
        """The (first) file written for ``target``: ``result.written("onnx")``."""
        if target not in self.files:
            raise InvalidValueError(f"no {target} file was written (targets: {', '.join(self.files) or 'none'})")
        return self.files[target][0].path


def export_and_check(
    source: ExportSource,
    model: FixedPointModel | None,
    targets: Sequence[str],
    out: str | Path,
    *,
    inhibition: float = WTA_INHIBITION,
    wta_node: bool = False,
    spikes: torch.Tensor | None = None,
    spikes_label: str = "",
    nir_consumer: str = "nirtorch",
    nir_tolerance: float | None = None,
    device: torch.device | None = None,
    overwrite: bool = True,
    progress: bool = False,
) -> ExportResult:
    """Write the targets into ``out``, check them on ``spikes`` when given, write export.json; return its content.

    The folder is built beside ``out`` and put in its place whole (:func:`vprsnn_export.io.fileio.publish_folder`),
    export.json last: a reader never sees new files beside old ones, and an interrupted export leaves the previous
    folder as it was. An existing ``out`` must be empty or an earlier export, replaced only with ``overwrite=True``.
    """
    out = Path(out)
    check_deploy_folder(out, overwrite=overwrite)
    staging = staging_folder(out)
    try:
        written = export_all(source, model, targets, staging, inhibition=inhibition, wta_node=wta_node)
        checks = None
        if spikes is not None:
            checks = check_exports(
                source,
                model,
                written,
                spikes,
                spikes_label=spikes_label,
                nir_consumer=nir_consumer,
                nir_tolerance=nir_tolerance,
                device=device,
                progress=progress,
            )
        result = ExportResult(
            folder=out,
            model=str(source.path),
            model_sha256=source.sha256,
            kind=source.kind,
            files={
                t: tuple(WrittenFile(out / p.relative_to(staging), sha256_file(p)) for p in paths)
                for t, paths in written.items()
            },
            consumers=consumer_statements(source, model, targets, wta_node, inhibition),
            checks=checks,
            cost=None if model is None else deployment_cost(model, spikes, spikes_label),
        )
        # export.json: every file's path relative to the deploy folder (``model.onnx``, ``loihi/network.json``),
        # so that the folder reads the same from any working directory and after a rename
        manifest = result.to_dict()
        manifest["files"] = {
            target: [{**entry, "path": Path(entry["path"]).relative_to(out).as_posix()} for entry in entries]
            for target, entries in manifest["files"].items()
        }
        atomic_write_text(staging / MANIFEST_NAME, json.dumps(manifest, indent=2))
        publish_folder(staging, out)
    finally:  # an interrupted export leaves no staging folder (a published one is no longer there)
        shutil.rmtree(staging, ignore_errors=True)
    return result


def contained_file(folder: Path, entry: WrittenFile, recorded_folder: str) -> WrittenFile:
    """The file export.json lists, inside ``folder``: a path relative to the folder (or, as export.json files
    of earlier versions recorded it, to the working directory, starting with the recorded folder), checked against
    its sha256. ModelFileError for an absolute path, a ``..`` part, a path (symbolic links followed) outside
    ``folder``, a missing file or one that differs from what export wrote."""
    listed = entry.path
    base = Path(recorded_folder)  # pathlib drops "." parts: a relative base starts with a name or ".."
    earlier = base.parts and base.parts[0] != ".." and not base.is_absolute()
    if earlier and listed.parts[: len(base.parts)] == base.parts:
        listed = listed.relative_to(base)  # an earlier version's path, relative to the working directory
    path = folder / listed
    try:
        inside = path.resolve().is_relative_to(folder.resolve())
    except (OSError, RuntimeError):
        inside = False
    if listed.is_absolute() or listed.drive:
        wrong = f"the absolute path {listed}: files must lie in its folder"
    elif ".." in listed.parts or not listed.parts:
        wrong = f"{listed}, which leaves its folder"
    elif not inside:
        wrong = f"{listed}, which resolves outside its folder"
    elif not path.is_file():
        wrong = f"{entry.path}, which is missing"
    elif sha256_file(path) != entry.sha256:
        raise ModelFileError(f"{entry.path} differs from what export wrote (sha256 mismatch)", folder)
    else:
        return WrittenFile(path, entry.sha256)
    raise ModelFileError(f"{MANIFEST_NAME} lists {wrong}", folder)


def check_deploy_folder(out: Path, *, overwrite: bool) -> None:
    """OutputError unless ``out`` is new, an empty folder, or (``overwrite``) an earlier export's folder."""
    check_output_folder(out)
    if (out / MANIFEST_NAME).is_file():
        if not overwrite:
            raise OutputError(f"holds an earlier export ({MANIFEST_NAME}): --force to replace it", out)
    elif out.exists() and any(out.iterdir()):
        raise OutputError(f"is a folder with other files and no {MANIFEST_NAME}: give a new or empty folder", out)


def read_export(folder: str | Path) -> ExportResult:
    """Read a deploy folder's export.json and check every file it lists against its sha256.

    ModelFileError when the manifest is missing or corrupt, or a file is missing or differs
    from what export wrote (an interrupted or mixed folder); the checks are not re-run.
    """
    folder = Path(folder)
    manifest = folder / MANIFEST_NAME
    if not manifest.is_file():
        raise ModelFileError(f"not a deploy folder: no {MANIFEST_NAME}", folder)
    try:
        data = parse_json(manifest.read_bytes(), MANIFEST_NAME)
        files = {
            target: tuple(WrittenFile(Path(f["path"]), str(f["sha256"])) for f in entries)
            for target, entries in data["files"].items()
        }
        result = ExportResult(
            folder=Path(str(data["folder"])),
            model=str(data["model"]),
            model_sha256=str(data["model_sha256"]),
            kind=str(data["kind"]),
            files=files,
            consumers={str(k): str(v) for k, v in data.get("consumers", {}).items()},
            cost=data.get("cost"),
        )
    except MANIFEST_ERRORS as exc:
        raise ModelFileError(f"corrupt {MANIFEST_NAME} ({exc})", manifest) from None
    recorded = str(data.get("folder", ""))
    checked = {target: tuple(contained_file(folder, e, recorded) for e in entries) for target, entries in files.items()}
    # the paths returned are the files just checked, under the folder as given here (not as recorded)
    return replace(result, folder=folder, files=checked)
