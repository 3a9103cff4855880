"""`vprsnn-export export` as a library: read a model, write NIR / Loihi-style / ONNX, check the files.

A model file is a float checkpoint (``train``) or a fixed-point model (``quantize``),
told apart by its container's ``format`` field (:func:`load_source`). NIR takes either;
the Loihi description and ONNX are integer targets and need a fixed-point model, which
a float checkpoint gets only on request (:func:`integer_model`: per-neuron max-abs
scales, the float calibration kept). :func:`check_exports` reads every written file
back and runs it beside the project's own simulators with the conformance harness of
:mod:`runtime.conformance` (exact), plus the measured agreement of a metadata-blind NIR
consumer (a measurement), and the NIR consumer gate (:mod:`runtime.consumer_gate`): every
installed float consumer must decide as the network does within the file's stated tolerance.
"""

from __future__ import annotations

import json
import shutil
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from vprsnn_export.checkpoint import FORMAT as CHECKPOINT_FORMAT
from vprsnn_export.checkpoint import Checkpoint, load_checkpoint
from vprsnn_export.dataset import load_dataset
from vprsnn_export.encoding import encode, query_spikes
from vprsnn_export.errors import InvalidValueError, ModelFileError
from vprsnn_export.export.model import FORMAT as FIXED_FORMAT
from vprsnn_export.export.model import FixedPointModel, check_bits, load_fixed_point
from vprsnn_export.fileio import (
    OutputError,
    atomic_write_text,
    check_output_folder,
    parse_json,
    publish_folder,
    read_container,
    sha256_file,
    staging_folder,
)
from vprsnn_export.targets.nir_read import load_graph
from vprsnn_export.targets.nir_runners import CONSUMERS, spike_agreement
from vprsnn_export.targets.nir_target import WTA_INHIBITION, apply_readout_rule
from vprsnn_export.targets.registry import TARGETS, WriteOptions

from .conformance import (
    Contender,
    backend_of,
    compare_backends,
    conformance_rows,
    read_back,
    target_path,
    wprob_readout,
)
from .consumer_gate import consumer_gate, decided_places
from .deployment import deploy
from .results import Comparison

MANIFEST_NAME = "export.json"


@dataclass(frozen=True)
class ExportSource:
    """A model file read for export: exactly one of a float checkpoint and a fixed-point model."""

    path: Path
    sha256: str
    checkpoint: Checkpoint | None = None
    fixed_point: FixedPointModel | None = None

    def __post_init__(self) -> None:
        if (self.checkpoint is None) == (self.fixed_point is None):
            raise InvalidValueError("an ExportSource holds exactly one of a checkpoint and a fixed-point model")

    @classmethod
    def of(cls, network: Checkpoint | FixedPointModel, sha256: str, path: str | Path = "<in memory>") -> ExportSource:
        """A network held in memory (``sha256`` names it in the exported files' provenance)."""
        if isinstance(network, FixedPointModel):
            return cls(Path(path), sha256, fixed_point=network)
        return cls(Path(path), sha256, checkpoint=network)

    @property
    def network(self) -> Checkpoint | FixedPointModel:
        """What NIR exports and what the project's own simulator runs."""
        return self.checkpoint if self.checkpoint is not None else self._fixed()

    @property
    def is_float(self) -> bool:
        return self.checkpoint is not None

    @property
    def kind(self) -> str:
        return "float checkpoint" if self.is_float else "fixed-point model"

    @property
    def thresholds(self) -> np.ndarray:
        """The thresholds as stored (float for a checkpoint, integer mantissas for a fixed-point model)."""
        return self.checkpoint.thresholds if self.checkpoint is not None else self._fixed().threshold

    def _fixed(self) -> FixedPointModel:
        if self.fixed_point is None:
            raise InvalidValueError("not a fixed-point model")
        return self.fixed_point


def load_source(path: str | Path) -> ExportSource:
    """A checkpoint or a fixed-point model, chosen by the container's ``format`` field."""
    path = Path(path)
    meta, _ = read_container(path, "model")
    kind = meta.get("format")
    if kind == CHECKPOINT_FORMAT:
        return ExportSource(path, sha256_file(path), checkpoint=load_checkpoint(path))
    if kind == FIXED_FORMAT:
        return ExportSource(path, sha256_file(path), fixed_point=load_fixed_point(path))
    raise ModelFileError(f"neither a checkpoint nor a fixed-point model (format {kind!r})", path)


def parse_export_targets(raw: str) -> tuple[str, ...]:
    """``--to``: some of the registered targets (at least one); InvalidValueError otherwise."""
    return TARGETS.parse_list(raw, "--to")


def integer_model(source: ExportSource, bits: int | None, targets: Sequence[str]) -> FixedPointModel | None:
    """The fixed-point model the integer targets get, or None when none is asked for.

    A float checkpoint is quantised only when ``bits`` is given (per-neuron max-abs
    scales, the float calibration kept): :func:`runtime.deployment.deploy`.
    """
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
    return deploy(source.checkpoint, source.sha256, check_bits(bits), calibration="float")


def consumer_statements(
    source: ExportSource, model: FixedPointModel | None, targets: Sequence[str], wta_node: bool, inhibition: float
) -> dict[str, str]:
    """What each consumer of each written file computes, in one sentence or three (each target's ``statement``)."""
    options = WriteOptions(source.sha256, inhibition, wta_node)
    notes: dict[str, str] = {}
    for entry in TARGETS.values():
        if entry.name in targets and (model is not None or not entry.integer_only):
            note = entry.statement(source.network, model, options)
            if note is not None:
                notes[entry.name] = note
    return notes


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
    integer = [name for name in TARGETS if name in wanted and TARGETS.get(name).integer_only]
    if integer and model is None:
        raise InvalidValueError(f"{' and '.join(integer)} need a fixed-point model")
    options = WriteOptions(source.sha256, inhibition, wta_node)
    written: dict[str, list[Path]] = {}
    for entry in TARGETS.values():
        if entry.name in wanted:
            network = model if entry.integer_only and model is not None else source.network
            written[entry.name] = entry.write(network, out / entry.filename, options)
    return written


# ---------------------------------------------------------------------------- checks


@dataclass(frozen=True)
class CheckRow:
    """One line of the check table: an exact check (``ok`` True/False) or a measurement (``ok`` None)."""

    target: str
    check: str
    ok: bool | None
    detail: str

    @property
    def result(self) -> str:
        return "-" if self.ok is None else ("ok" if self.ok else "FAILED")

    def to_dict(self) -> dict[str, str]:
        return {"target": self.target, "check": self.check, "result": self.result, "detail": self.detail}


@dataclass(frozen=True)
class ExportChecks:
    """Every written file read back and run: the exact comparisons and the measurements."""

    spikes: str  # what was presented
    comparisons: tuple[Comparison, ...]
    measurements: tuple[CheckRow, ...] = ()

    @property
    def passed(self) -> bool:
        return all(c.equal for c in self.comparisons)

    @property
    def rows(self) -> list[CheckRow]:
        exact = [
            CheckRow(r["target"], r["check"], r["result"] == "ok", r["detail"])
            for r in conformance_rows(self.comparisons)
        ]
        return exact + list(self.measurements)

    def to_dict(self) -> dict[str, Any]:
        return {"spikes": self.spikes, "rows": [r.to_dict() for r in self.rows], "passed": self.passed}


def check_presentations(
    source: ExportSource,
    query: str | None,
    *,
    data: str | None = None,
    subset: str | None = None,
    places: str | None = None,
    samples: int = 16,
    progress: bool = False,
) -> tuple[torch.Tensor, str]:
    """Query presentations of ``query`` (real data; the model's own data selection unless given),
    else ``samples`` synthetic Bernoulli trains of random images."""
    network = source.network
    cfg = network.config
    if query:
        if subset is None and places is None:
            subset, places = network.data.get("subset"), network.data.get("places")
        origin = data or network.data.get("source")
        if not origin:
            raise InvalidValueError("the model names no data source: give --data")
        dataset = load_dataset(origin, [query], cfg.preprocess, subset=subset, places=places, progress=progress)
        images, ids = dataset.traversal(query), dataset.place_ids
        if samples > 0:
            images, ids = images[:samples], ids[:samples]
        return query_spikes(images, ids, query, cfg), f"{len(ids)} '{query}' queries from {dataset.source}"
    n = samples if samples > 0 else 16
    rng = np.random.default_rng(cfg.seed)
    spikes = encode(rng.random((n, cfg.network.n_inputs)).astype(np.float32), list(range(n)), cfg.encoder)
    return spikes, f"{n} synthetic presentations (uniform random pixels)"


def nir_consumer_rows(
    path: Path, network: Checkpoint | FixedPointModel, raster: torch.Tensor, spikes: torch.Tensor, consumer_name: str
) -> list[CheckRow]:
    """How far a metadata-blind NIR consumer is from the network (measured, not checked)."""
    graph = load_graph(path)
    try:
        consumer = CONSUMERS[consumer_name](graph, spikes)
    except (
        AssertionError,
        ValueError,
    ) as exc:  # snnTorch asserts, SpikingJelly raises ValueError on what they cannot express
        return [CheckRow("nir", f"{consumer_name} loads the file", None, f"refused: {exc}")]
    agreement = spike_agreement(raster, consumer)
    rows: list[CheckRow] = []
    if "wta" not in graph.nodes:
        ruled = apply_readout_rule(graph, spikes, consumer)
        differing = int((ruled != raster.to(torch.bool)).sum())
        rows.append(
            CheckRow(
                "nir",
                f"{consumer_name} + readout rule (metadata) vs network",
                None,
                f"{differing} differing raster entries of {raster.numel()}",
            )
        )
    places = decided_places(network, raster.sum(dim=1).numpy())
    consumer_places = decided_places(network, consumer.sum(dim=1).numpy())
    rate = consumer.sum().item() / max(1, consumer.shape[0] * consumer.shape[1])
    return [
        *rows,
        CheckRow(
            "nir",
            f"{consumer_name} (no metadata) vs network",
            None,
            f"recall {agreement['recall']:.4f}, precision {agreement['precision']:.4f}, {rate:.1f} spikes/step",
        ),
        CheckRow(
            "nir",
            f"{consumer_name} top-1 place (W+Prob) == network's",
            None,
            f"{float(np.mean(places == consumer_places)):.3f}",
        ),
    ]


def check_exports(
    source: ExportSource,
    model: FixedPointModel | None,
    written: Mapping[str, Sequence[Path]],
    spikes: torch.Tensor,
    *,
    spikes_label: str = "",
    nir_consumer: str = "nirtorch",
    nir_tolerance: float | None = None,
    device: torch.device | None = None,
    progress: bool = False,
) -> ExportChecks:
    """Read every written file back and run it against the project's simulator of what it was written from."""
    comparisons: list[Comparison] = []
    measurements: list[CheckRow] = []
    integer = [t for t in TARGETS if t in written and TARGETS.get(t).integer_only]
    stages = ["nir"] * ("nir" in written) + ["integer"] * bool(integer and model is not None)
    for stage in tqdm(stages, desc="checking exports", unit="target", file=sys.stderr, disable=not progress):
        if stage == "nir":
            network = source.network
            baseline = backend_of(network, device)
            base_run = baseline.run(spikes, record=True)
            path = target_path("nir", written["nir"])
            contender = read_back("nir", path, network, device)
            comparisons += compare_backends(baseline, [contender], spikes, baseline_run=base_run)
            if base_run.raster is not None:
                measurements += nir_consumer_rows(path, network, base_run.raster, spikes, nir_consumer)
                comparisons += consumer_gate(path, network, base_run.raster, spikes, tolerance=nir_tolerance)
        elif model is not None:
            contenders: list[Contender] = [read_back(t, target_path(t, written[t]), model, device) for t in integer]
            comparisons += compare_backends(backend_of(model, device), contenders, spikes, wprob=wprob_readout(model))
    return ExportChecks(spikes_label, tuple(comparisons), tuple(measurements))


# ---------------------------------------------------------------------------- the whole export


@dataclass(frozen=True)
class WrittenFile:
    path: Path
    sha256: str

    def to_dict(self) -> dict[str, str]:
        return {"path": str(self.path), "sha256": self.sha256}


@dataclass(frozen=True)
class ExportResult:
    """What `export` wrote (export.json): the folder, the model, every file with its hash, the consumers, the checks."""

    folder: Path
    model: str
    model_sha256: str
    kind: str
    files: Mapping[str, tuple[WrittenFile, ...]]
    consumers: Mapping[str, str]
    checks: ExportChecks | None = None

    @property
    def passed(self) -> bool:
        return self.checks is None or self.checks.passed

    def written(self, target: str) -> Path:
        """The (first) file written for ``target``: ``result.written("onnx")``."""
        if target not in self.files:
            raise InvalidValueError(f"no {target} file was written (targets: {', '.join(self.files) or 'none'})")
        return self.files[target][0].path

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {
            "folder": str(self.folder),
            "model": self.model,
            "model_sha256": self.model_sha256,
            "kind": self.kind,
            "files": {t: [f.to_dict() for f in files] for t, files in self.files.items()},
            "consumers": dict(self.consumers),
        }
        if self.checks is not None:
            data["checks"] = self.checks.to_dict()
        return data


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

    The folder is built as a whole beside ``out`` and then put in its place
    (:func:`vprsnn_export.fileio.publish_folder`), export.json last: a reader never sees new
    files beside old ones, and an interrupted export leaves the previous folder as it was.
    An existing ``out`` must be empty or an earlier export (it holds export.json); that one is
    replaced only with ``overwrite=True``.
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
        )
        atomic_write_text(staging / MANIFEST_NAME, json.dumps(result.to_dict(), indent=2))
        publish_folder(staging, out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return result


def check_deploy_folder(out: Path, *, overwrite: bool) -> None:
    """OutputError unless ``out`` is new, an empty folder, or (``overwrite``) an earlier export's folder."""
    check_output_folder(out)
    if not out.exists():
        return
    if (out / MANIFEST_NAME).is_file():
        if not overwrite:
            raise OutputError(f"holds an earlier export ({MANIFEST_NAME}): --force to replace it", out)
        return
    if any(out.iterdir()):
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
        )
    except (
        OSError,
        UnicodeDecodeError,
        json.JSONDecodeError,
        InvalidValueError,
        KeyError,
        TypeError,
        AttributeError,
    ) as exc:
        raise ModelFileError(f"corrupt {MANIFEST_NAME} ({exc})", manifest) from None
    base = Path(str(data.get("folder", "")))
    for entries in files.values():
        for entry in entries:
            try:
                path = folder / entry.path.relative_to(base)
            except ValueError:
                raise ModelFileError(f"{MANIFEST_NAME} lists {entry.path}, outside its folder {base}", folder) from None
            if not path.is_file():
                raise ModelFileError(f"{MANIFEST_NAME} lists {entry.path}, which is missing", folder)
            if sha256_file(path) != entry.sha256:
                raise ModelFileError(f"{entry.path} differs from what export wrote (sha256 mismatch)", folder)
    return result


__all__ = [
    "MANIFEST_NAME",
    "CheckRow",
    "ExportChecks",
    "ExportResult",
    "ExportSource",
    "WrittenFile",
    "check_exports",
    "check_deploy_folder",
    "check_presentations",
    "consumer_statements",
    "export_all",
    "export_and_check",
    "integer_model",
    "load_source",
    "parse_export_targets",
    "read_export",
]
