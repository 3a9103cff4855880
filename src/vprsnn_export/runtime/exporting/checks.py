"""Every written file read back and run beside the project's simulators (:func:`check_exports`): exact checks and measurements."""

from __future__ import annotations

import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from vprsnn_export.data.dataset import load_selection
from vprsnn_export.data.encoding import encode, query_spikes
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.io.serial import JsonDataclass, json_options
from vprsnn_export.targets.nir_read import load_graph
from vprsnn_export.targets.nir_runners import CONSUMERS, spike_agreement
from vprsnn_export.targets.nir_target import apply_readout_rule
from vprsnn_export.targets.registry import TARGETS

from ..backends import open_backend
from ..conformance import compare_backends, read_back, wprob_readout
from ..consumer_gate import consumer_gate, decided_places
from ..results import Comparison
from .source import ExportSource


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
class ExportChecks(JsonDataclass):
    """Every written file read back and run: the exact comparisons and the measurements (JSON: the rows)."""

    spikes: str  # what was presented
    comparisons: tuple[Comparison, ...] = field(metadata=json_options(write=False))
    measurements: tuple[CheckRow, ...] = field(default=(), metadata=json_options(write=False))

    __json_extra__ = ("rows", "passed")

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.comparisons)

    @property
    def rows(self) -> list[CheckRow]:
        """The exact checks (under their target, the label before ':'), then the measurements."""
        names = {entry.label: entry.name for entry in TARGETS.values()}  # the check tables' first column
        rows = []
        for c in self.comparisons:
            prefix, _, what = c.check.partition(": ")
            rows.append(CheckRow(names.get(prefix, prefix), f"{what or prefix}: {c.a} vs {c.b}", c.passed, c.detail))
        return rows + list(self.measurements)


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
        dataset = load_selection(
            network.data, [query], cfg.preprocess, source=data, subset=subset, places=places, progress=progress
        )
        first = slice(samples if samples > 0 else None)  # the first ``samples`` queries (0: all)
        images, ids = dataset.traversal(query)[first], dataset.place_ids[first]
        return query_spikes(images, ids, query, cfg), f"{len(ids)} '{query}' queries from {dataset.source}"
    n = samples if samples > 0 else 16
    rng = np.random.default_rng(cfg.seed)
    spikes = encode(rng.random((n, cfg.network.n_inputs)).astype(np.float32), list(range(n)), cfg.encoder)
    return spikes, f"{n} synthetic presentations (uniform random pixels)"


def nir_consumer_rows(
    path: Path,
    network: Checkpoint | FixedPointModel,
    raster: torch.Tensor,
    spikes: torch.Tensor,
    consumer_name: str,
    target: str,
) -> list[CheckRow]:
    """How far a metadata-blind consumer of a NIR file (target ``target``) is from the network (measured, not checked)."""
    graph = load_graph(path)

    def row(check: str, detail: str) -> CheckRow:
        return CheckRow(target, f"{consumer_name} {check}", None, detail)

    try:
        consumer = CONSUMERS[consumer_name](graph, spikes)
    # snnTorch asserts, SpikingJelly raises ValueError on what they cannot express
    except (AssertionError, ValueError) as exc:
        return [row("loads the file", f"refused: {exc}")]
    agreement = spike_agreement(raster, consumer)
    rows: list[CheckRow] = []
    if "wta" not in graph.nodes:
        differing = int((apply_readout_rule(graph, spikes, consumer) != raster.to(torch.bool)).sum())
        rows.append(
            row("+ readout rule (metadata) vs network", f"{differing} differing raster entries of {raster.numel()}")
        )
    places = decided_places(network, raster.sum(dim=1).numpy())
    consumer_places = decided_places(network, consumer.sum(dim=1).numpy())
    rate = consumer.sum().item() / max(1, consumer.shape[0] * consumer.shape[1])
    measured = f"recall {agreement['recall']:.4f}, precision {agreement['precision']:.4f}, {rate:.1f} spikes/step"
    return [
        *rows,
        row("(no metadata) vs network", measured),
        row("top-1 place (W+Prob) == network's", f"{float(np.mean(places == consumer_places)):.3f}"),
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
    entries = [TARGETS.get(t) for t in TARGETS if t in written]
    integer = [entry.name for entry in entries if entry.integer_only]
    stages = [entry for entry in entries if not entry.integer_only] + ["integer"] * bool(integer and model is not None)
    for stage in tqdm(stages, desc="checking exports", unit="target", file=sys.stderr, disable=not progress):
        if not isinstance(stage, str):  # a target written from the source itself, float or fixed point
            network = source.network
            baseline = open_backend(network, device=device)[1]
            base_run = baseline.run(spikes, record=True)
            path = stage.reader_path(written[stage.name])
            contender = read_back(stage.name, path, network, device)
            comparisons += compare_backends(baseline, [contender], spikes, baseline_run=base_run)
            if base_run.raster is not None and stage.float_consumers:
                measurements += nir_consumer_rows(path, network, base_run.raster, spikes, nir_consumer, stage.name)
                comparisons += consumer_gate(
                    path, network, base_run.raster, spikes, tolerance=nir_tolerance, label=stage.label
                )
        elif model is not None:
            contenders = [read_back(t, TARGETS.get(t).reader_path(written[t]), model, device) for t in integer]
            comparisons += compare_backends(
                open_backend(model, device=device)[1], contenders, spikes, wprob=wprob_readout(model)
            )
    return ExportChecks(spikes_label, tuple(comparisons), tuple(measurements))
