"""Write the deployment files of a network and say what each consumer computes: the library behind `export`.

The source is a float checkpoint (``train``) or a fixed-point model (``quantize``), told
apart by the ``format`` field of its container. NIR takes either. The Loihi-style
description and ONNX are integer targets: they need a fixed-point model, so a float
checkpoint is quantised on the fly only when asked (per-neuron max-abs scales, float
calibration kept; `quantize` offers every other choice).

:func:`export_network` writes the files and ``export.json`` (written last: a folder
whose manifest is missing or names other hashes is not a finished export); with spikes
it also checks every file read back (:mod:`vprsnn_export.runtime.conformance`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vprsnn_export.checkpoint import FORMAT as CHECKPOINT_FORMAT
from vprsnn_export.checkpoint import Checkpoint, load_checkpoint
from vprsnn_export.config import Config
from vprsnn_export.dynamics import FloatNetwork
from vprsnn_export.encoding import encode, query_spikes
from vprsnn_export.errors import InvalidValueError, ModelFileError
from vprsnn_export.export.model import FORMAT as FIXED_FORMAT
from vprsnn_export.export.model import FixedPointModel, check_bits, load_fixed_point
from vprsnn_export.export.quantize import quantize_checkpoint
from vprsnn_export.fileio import atomic_write_text, read_container, sha256_file
from vprsnn_export.readout.assignment import decide, strategy_scores
from vprsnn_export.runs import SpikeRun
from vprsnn_export.targets.intsim import IntegerNetwork
from vprsnn_export.targets.loihi_target import write_loihi
from vprsnn_export.targets.nir_target import CONSUMERS, WTA_INHIBITION, load_graph, read_nir, spike_agreement, write_nir
from vprsnn_export.targets.onnx_target import write_onnx

from .conformance import Comparison, check_conformance, compare_runs

TARGETS = ("nir", "loihi", "onnx")
INTEGER_TARGETS = ("loihi", "onnx")
NIR_NAME = "model.nir"
ONNX_NAME = "model.onnx"
LOIHI_DIR = "loihi"
MANIFEST_NAME = "export.json"

Network = Checkpoint | FixedPointModel
"""What can be exported: a float checkpoint or a fixed-point model."""


def parse_targets(raw: str, option: str = "--to", *, allow_none: bool = False) -> tuple[str, ...]:
    """``"nir,onnx"`` -> ("nir", "onnx"); InvalidValueError naming the option on anything else."""
    names = tuple(dict.fromkeys(v.strip().lower() for v in raw.split(",") if v.strip()))
    if allow_none and names == ("none",):
        return ()
    unknown = [n for n in names if n not in TARGETS]
    if not names or unknown:
        extra = " (or none)" if allow_none else ""
        raise InvalidValueError(f"{option} expects some of {', '.join(TARGETS)}{extra}, got {raw!r}")
    return names


def load_network(path: str | Path) -> Network:
    """A Checkpoint or a FixedPointModel, chosen by the container's ``format`` field."""
    meta, _ = read_container(path, "model")
    kind = meta.get("format")
    if kind == CHECKPOINT_FORMAT:
        return load_checkpoint(path)
    if kind == FIXED_FORMAT:
        return load_fixed_point(path)
    raise ModelFileError(f"neither a checkpoint nor a fixed-point model (format {kind!r})", path)


def integer_model(source: Network, bits: int | None, digest: str, targets: Sequence[str]) -> FixedPointModel | None:
    """The fixed-point model the integer targets get, or None when none is asked for."""
    if isinstance(source, FixedPointModel):
        if bits is not None:
            raise InvalidValueError("--quantize applies to float checkpoints; this is already a fixed-point model")
        return source
    wanted = [t for t in targets if t in INTEGER_TARGETS]
    if not wanted:
        return None
    if bits is None:
        raise InvalidValueError(
            f"{' and '.join(wanted)} need a fixed-point model: run `vprsnn-export quantize CHECKPOINT --bits 8 "
            "--per-neuron --out DIR` and export the model it writes, add --quantize 8 here, or export with --to nir"
        )
    return quantize_checkpoint(source, digest, check_bits(bits), per_neuron=True, scale_method="max")


def consumer_statements(
    source: Network, model: FixedPointModel | None, targets: Sequence[str], wta_node: bool, inhibition: float
) -> dict[str, str]:
    """What each consumer of each written file computes, in one sentence or three."""
    fixed = isinstance(source, FixedPointModel)
    thresholds = source.threshold if isinstance(source, FixedPointModel) else source.thresholds
    uniform = bool(np.all(thresholds == thresholds[0]))
    notes: dict[str, str] = {}
    if "nir" in targets:
        arithmetic = (
            "float arithmetic on integer mantissas (no round-toward-zero decay, no 24-bit saturation)"
            if fixed
            else "the float network's own arithmetic"
        )
        inhibit = (
            f"plus lateral inhibition ({inhibition} of its threshold per other spike, one step later)"
            if wta_node and inhibition > 0
            else "with no inhibition"
        )
        notes["nir"] = (
            "vprsnn-export's read_nir rebuilds the network exactly (WTA from the metadata). A consumer that reads "
            f"only the nodes (nirtorch with NIR's LIF, snnTorch, Norse) computes {arithmetic}, every neuron over "
            f"threshold spiking (no WTA) {inhibit}. At dt = 1e-4 s Euler gives "
            "v <- beta v + I; Norse ignores r (input scaled by 1 - beta); snnTorch's importer needs one threshold "
            f"for all neurons ({'met' if uniform else 'not met by this model'})"
            + (
                ""
                if not wta_node
                else "; snnTorch's importer starves a LIF with a recurrent Linear and Norse returns "
                "the wta node's output instead of the spikes (--nir-no-wta-node avoids both)"
            )
            + "."
        )
    if "onnx" in targets and model is not None:
        notes["onnx"] = (
            "onnxruntime computes the integer network exactly: spike counts, saturations and the W+Prob "
            "distribution, identical to the integer simulator."
        )
    if "loihi" in targets and model is not None:
        notes["loihi"] = (
            "Lava's bit-accurate Dense + LIF (fixed_pt) compute the candidate raster bit for bit (WTA off) while "
            "a_j < 2**17; the hard WTA is a rule in network.json that a Lava user adds after the LIF population."
        )
    return notes


def write_targets(
    source: Network,
    model: FixedPointModel | None,
    targets: Sequence[str],
    out: Path,
    *,
    digest: str | None = None,
    inhibition: float = WTA_INHIBITION,
    wta_node: bool = True,
    onnx_raster: bool = False,
) -> tuple[dict[str, list[Path]], dict[str, str]]:
    """Write each target into ``out``: (target -> files written, target -> why it was skipped).

    NIR describes ``source`` (float or fixed point); ONNX and Loihi need ``model``. A target
    whose format cannot express the model (e.g. ONNX with state isolation off) is skipped
    with its reason.
    """
    written: dict[str, list[Path]] = {}
    skipped: dict[str, str] = {}
    if "nir" in targets:
        written["nir"] = [
            write_nir(source, out / NIR_NAME, source_sha256=digest, wta_inhibition=inhibition, wta_node=wta_node)
        ]
    if model is not None and "onnx" in targets:
        try:
            written["onnx"] = [write_onnx(model, out / ONNX_NAME, with_wprob=True, with_raster=onnx_raster)]
        except InvalidValueError as exc:  # the graph cannot express the model (state isolation off)
            skipped["onnx"] = str(exc)
    if model is not None and "loihi" in targets:
        written["loihi"] = list(write_loihi(model, out / LOIHI_DIR, source_sha256=digest).values())
    return written, skipped


def check_spikes(
    cfg: Config, images: np.ndarray | None, place_ids: np.ndarray | None, query: str | None, limit: int
) -> tuple[torch.Tensor, str]:
    """The spikes `export --check` presents: real query presentations, else synthetic trains of random images."""
    if images is not None and place_ids is not None and query is not None:
        if limit > 0:
            images, place_ids = images[:limit], place_ids[:limit]
        return query_spikes(images, place_ids, query, cfg), f"{len(place_ids)} '{query}' queries"
    n = limit if limit > 0 else 16
    rng = np.random.default_rng(cfg.seed)
    spikes = encode(rng.random((n, cfg.network.n_inputs)).astype(np.float32), list(range(n)), cfg.encoder)
    return spikes, f"{n} synthetic presentations (uniform random pixels)"


@dataclass(frozen=True)
class CheckRow:
    """One line of the `export --check` table: an exact check (ok / FAILED) or a measurement (-)."""

    target: str
    check: str
    result: str  # "ok", "FAILED" or "-"
    detail: str

    def to_dict(self) -> dict[str, str]:
        return {"target": self.target, "check": self.check, "result": self.result, "detail": self.detail}


def _target_of(check: str) -> str:
    for prefix, target in (("ONNX", "onnx"), ("NIR", "nir"), ("Loihi", "loihi"), ("reference", "reference")):
        if check.startswith(prefix):
            return target
    return "-"


def check_rows(comparisons: Sequence[Comparison]) -> list[CheckRow]:
    """Exact comparisons as table rows."""
    return [CheckRow(_target_of(c.check), c.check, "ok" if c.equal else "FAILED", c.detail) for c in comparisons]


def _float_run(ckpt: Checkpoint, spikes: torch.Tensor) -> SpikeRun:
    return FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, ckpt.config, torch.device("cpu")).run(
        spikes, record=True
    )


def _decided_places(calibration: np.ndarray, gamma: float, counts: np.ndarray) -> np.ndarray:
    return decide(strategy_scores(calibration, counts, "wprob", gamma), "wprob")[0]


def consumer_rows(
    path: Path, source: Network, network: SpikeRun, spikes: torch.Tensor, consumer: str
) -> list[CheckRow]:
    """A metadata-blind NIR consumer (nirtorch, snnTorch, Norse) measured against the network's raster."""
    assert network.raster is not None
    try:
        raster = CONSUMERS[consumer](load_graph(path), spikes)
    except AssertionError as exc:  # snnTorch's importer asserts on what it cannot express
        return [CheckRow("nir", f"{consumer} loads the file", "-", f"refused: {exc}")]
    agreement = spike_agreement(network.raster, raster)
    gamma = source.config.assignment.gamma
    places = _decided_places(source.calibration, gamma, network.raster.sum(dim=1).numpy())
    consumer_places = _decided_places(source.calibration, gamma, raster.sum(dim=1).numpy())
    per_step = raster.sum().item() / max(1, raster.shape[0] * raster.shape[1])
    return [
        CheckRow(
            "nir",
            f"{consumer} (no metadata) vs network",
            "-",
            f"recall {agreement['recall']:.4f}, precision {agreement['precision']:.4f}, {per_step:.1f} spikes/step",
        ),
        CheckRow(
            "nir", f"{consumer} top-1 place (W+Prob) == network's", "-", f"{np.mean(places == consumer_places):.3f}"
        ),
    ]


@dataclass(frozen=True)
class ExportResult:
    """What `export` wrote (export.json) and, with spikes, how every file read back compares."""

    model: str
    model_sha256: str
    kind: str
    files: dict[str, list[dict[str, str]]]
    consumers: dict[str, str]
    skipped: dict[str, str] = field(default_factory=dict)
    spikes: str | None = None
    checks: tuple[CheckRow, ...] | None = None

    @property
    def passed(self) -> bool:
        return self.checks is None or all(row.result != "FAILED" for row in self.checks)

    def written(self, target: str) -> Path:
        """The (first) file written for ``target``: ``result.written("onnx")``."""
        if target not in self.files:
            raise InvalidValueError(f"no {target} file was written (targets: {', '.join(self.files) or 'none'})")
        return Path(self.files[target][0]["path"])

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "model": self.model,
            "model_sha256": self.model_sha256,
            "kind": self.kind,
            "files": self.files,
            "consumers": self.consumers,
        }
        if self.skipped:
            out["skipped"] = self.skipped
        if self.checks is not None:
            out["checks"] = {
                "spikes": self.spikes,
                "rows": [row.to_dict() for row in self.checks],
                "passed": self.passed,
            }
        return out


def export_network(
    source: Network,
    model: FixedPointModel | None,
    targets: Sequence[str],
    out: str | Path,
    *,
    digest: str,
    model_path: str = "",
    inhibition: float = WTA_INHIBITION,
    wta_node: bool = True,
    spikes: torch.Tensor | None = None,
    spikes_label: str = "",
    nir_consumer: str = "nirtorch",
) -> ExportResult:
    """Write the targets into ``out``, check them on ``spikes`` when given, write export.json last.

    ``source`` is what NIR describes, ``model`` the fixed-point model for the integer targets
    (:func:`integer_model`).
    """
    folder = Path(out)
    written, skipped = write_targets(
        source, model, targets, folder, digest=digest, inhibition=inhibition, wta_node=wta_node
    )
    rows: list[CheckRow] | None = None
    if spikes is not None:
        rows = check_written(source, model, written, spikes, nir_consumer)
    result = ExportResult(
        model=model_path,
        model_sha256=digest,
        kind="float checkpoint" if isinstance(source, Checkpoint) else "fixed-point model",
        files={t: [{"path": str(p), "sha256": sha256_file(p)} for p in paths] for t, paths in written.items()},
        consumers=consumer_statements(source, model, targets, wta_node, inhibition),
        skipped=skipped,
        spikes=spikes_label if spikes is not None else None,
        checks=None if rows is None else tuple(rows),
    )
    atomic_write_text(folder / MANIFEST_NAME, json.dumps(result.to_dict(), indent=2))
    return result


def check_written(
    source: Network,
    model: FixedPointModel | None,
    written: Mapping[str, Sequence[Path]],
    spikes: torch.Tensor,
    nir_consumer: str,
) -> list[CheckRow]:
    """Every written file read back and run on ``spikes``, against the project's own network."""
    rows: list[CheckRow] = []
    if isinstance(source, Checkpoint):
        network = _float_run(source, spikes)
        if "nir" in written:
            rebuilt = read_nir(written["nir"][0])
            assert isinstance(rebuilt, Checkpoint)
            rows += check_rows(
                compare_runs("NIR read back", "float network", network, "read_nir rebuild", _float_run(rebuilt, spikes))
            )
    if model is not None:
        baseline = IntegerNetwork(model).run(spikes, record=True)
        files = {t: list(p) for t, p in written.items() if t != "nir" or isinstance(source, FixedPointModel)}
        rows += check_rows(check_conformance(model, spikes, baseline, files).comparisons)
    if isinstance(source, FixedPointModel):
        network = baseline
    if "nir" in written:
        rows += consumer_rows(written["nir"][0], source, network, spikes, nir_consumer)
    return rows
