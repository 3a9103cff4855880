"""One float checkpoint verified at every bit width (:func:`verify_checkpoint`): deploy, export, run, check."""

from __future__ import annotations

import sys
import tempfile
import time
from collections.abc import Mapping
from contextlib import nullcontext
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from vprsnn_export.arguments import require_type
from vprsnn_export.config import Config, VerifyConfig
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.data.truth import Query
from vprsnn_export.export.model import DEFAULT_BITS, check_bits, save_fixed_point
from vprsnn_export.export.quantize import DEFAULT_QUANTISE, QuantiseOptions
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.network.cost import query_cost
from vprsnn_export.network.modules import module_regions
from vprsnn_export.network.runs import SpikeRun
from vprsnn_export.readout.scored import Scored
from vprsnn_export.readout.scoring import Readout
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.targets.registry import TARGETS

from ..backends import open_backend
from ..conformance import cross_implementation
from ..consumer_gate import with_consumer_gate
from ..deployment import check_reference_images, deploy
from ..results import BitsResult, FloatResult, VerifiedRun
from .checks import (
    DEFAULT_TOLERANCES,
    curves,
    decision_level,
    judged_limits,
    level_histogram,
    metric_deltas,
    module_rows,
    spike_level,
    tolerance_checks,
    weight_histograms,
)
from .paired import bits_passed, paired_checks


@dataclass(frozen=True)
class VerifyOptions:
    """What `verify` quantises and how it reads out and judges."""

    readout: SequenceOptions
    bits: tuple[int, ...] = DEFAULT_BITS
    quantise: QuantiseOptions = DEFAULT_QUANTISE  # how each width is quantised and calibrated
    reference_queries: int = 3  # presentations run on the slow reference stepper
    targets: tuple[str, ...] = field(default_factory=TARGETS.names)  # every registered target
    tolerances: dict[str, float | None] = field(default_factory=lambda: dict(DEFAULT_TOLERANCES))
    statistics: VerifyConfig = field(default_factory=VerifyConfig)  # the paired verdict's settings

    def __post_init__(self) -> None:
        require_type("readout", self.readout, SequenceOptions)
        require_type("quantise", self.quantise, QuantiseOptions)
        object.__setattr__(self, "bits", tuple(check_bits(b) for b in self.bits))

    def to_dict(self, config: Config) -> dict[str, Any]:
        """The settings of a report: the quantisation options beside the bit widths (per_neuron, scale_method,
        fold_thresholds, calibration, non_leaky), the readout with the gamma of ``config`` (the networks' config)."""
        data = asdict(self)
        readout = {"gamma": config.assignment.gamma, **data.pop("readout")}
        return {"readout": readout, "bits": data.pop("bits"), **data.pop("quantise"), **data}


#: Most raster entries (queries x steps x neurons, one byte each) a recorded run may hold: the
#: step-level checks (winner agreement, the exported files' rasters) run on the first queries that
#: fit, the metrics on all of them (a whole route: 2400 queries x 300 steps x 9600 neurons would be
#: 6.9 GB per raster).
RASTER_BUDGET = 1 << 29


@dataclass(frozen=True, eq=False)
class VerifiedNetwork:
    """The float network `verify` checks: its checkpoint, the sha256 of its file, the images of its reference
    traversals in its reference place order (the deployed calibration needs them), its name in the report and
    its file's path."""

    checkpoint: Checkpoint
    sha256: str
    reference_images: Mapping[str, np.ndarray] | None = None
    label: str | None = None
    path: str | None = None

    def __post_init__(self) -> None:
        require_type("checkpoint", self.checkpoint, Checkpoint)
        require_type("sha256", self.sha256, str)
        require_type("reference_images", self.reference_images, (Mapping, type(None)))


@dataclass(frozen=True)
class Runtime:
    """Where a verification runs: the torch device, a progress bar, the folder that keeps each width's files
    (None: a temporary one)."""

    device: torch.device = torch.device("cpu")
    progress: bool = False
    export_dir: str | Path | None = None

    def __post_init__(self) -> None:
        require_type("device", self.device, torch.device)
        require_type("progress", self.progress, bool)
        require_type("export_dir", self.export_dir, (str, Path, type(None)))


@dataclass(frozen=True, eq=False)
class FloatSide:
    """The float network on the queries: its spikes, the run of the first ``recorded`` (with the raster), every
    query's counts and its readout, decided once."""

    spikes: torch.Tensor
    recorded: int
    run: SpikeRun
    counts: np.ndarray
    scored: Scored


def verify_checkpoint(
    network: VerifiedNetwork, query: Query, options: VerifyOptions, runtime: Runtime = Runtime()
) -> VerifiedRun:
    """Quantise the network at every bit width and run every check: one verified run of the report.

    Float and each width are read out once (a :class:`~vprsnn_export.readout.scored.Scored`); every check is a
    comparison of two of them (:mod:`vprsnn_export.readout.compare`, :mod:`.paired`). Each width's model and
    exported files go to ``runtime.export_dir``.
    """
    require_type("network", network, VerifiedNetwork)
    require_type("query", query, Query)
    require_type("options", options, VerifyOptions)
    require_type("runtime", runtime, Runtime)
    check_reference_images(options.quantise, network.reference_images)  # before the float side runs
    floats = float_side(network.checkpoint, query, options.readout, runtime)
    # each width's files: in runtime.export_dir, or in a temporary folder removed afterwards; a bar over its stages
    folder = (
        tempfile.TemporaryDirectory(prefix="vprsnn-verify-")
        if runtime.export_dir is None
        else nullcontext(str(runtime.export_dir))
    )
    bar = tqdm(total=len(options.bits) * 4, desc=f"verify {network.label or ''}".strip(), unit="stage",
               file=sys.stderr, disable=not runtime.progress, leave=False)  # fmt: skip
    with folder as root, bar as stages:
        results = tuple(
            verify_width(bits, network, query, options, floats, Path(root) / f"{bits}bit", runtime, stages)
            for bits in options.bits
        )
    return verified_run(network, query, options, floats, results, runtime.export_dir)


def verified_run(
    network: VerifiedNetwork,
    query: Query,
    options: VerifyOptions,
    floats: FloatSide,
    results: tuple[BitsResult, ...],
    export_dir: str | Path | None,
) -> VerifiedRun:
    """The report's record of one network verified at every width."""
    ckpt = network.checkpoint
    return VerifiedRun(
        label=network.label,
        seed=ckpt.config.seed,
        config=ckpt.config.to_dict(),
        checkpoint_sha256=network.sha256,
        checkpoint_data=dict(ckpt.data),
        query=query.traversal,
        n_queries=int(len(query.place_ids)),
        query_place_ids=tuple(int(p) for p in query.place_ids),
        reference_place_ids=tuple(int(p) for p in ckpt.reference_place_ids),
        export_dir=None if export_dir is None else str(export_dir),
        float=FloatResult(  # its rows, spikes, PR curves, weight histogram and cost per query
            metrics=tuple(floats.scored.rows),
            total_spikes=int(floats.counts.sum()),
            pr_curves=curves(floats.scored, options.readout.ks),
            weights=weight_histograms(ckpt.weights, options.quantise.per_neuron),
            cost=query_cost(
                floats.spikes, ckpt.weights.shape[1], places=len(ckpt.reference_place_ids), images=query.images
            ).summary(),
        ),
        bits=results,
        checkpoint=network.path,
        recorded_queries=floats.recorded,
    )


def float_side(ckpt: Checkpoint, query: Query, readout: SequenceOptions, runtime: Runtime) -> FloatSide:
    """The float network run on the queries' spikes (the first queries the raster budget holds recorded, at least
    one) and read out once."""
    spikes = query_spikes(query.images, query.place_ids, query.traversal, ckpt.config)
    recorded = int(min(spikes.shape[0], max(1, RASTER_BUDGET // max(1, spikes.shape[1] * ckpt.weights.shape[1]))))
    # a bar over the query chunks of each network run below
    network = open_backend(ckpt, "float", device=runtime.device, progress=runtime.progress)[1]
    run = network.run(spikes[:recorded], record=True)
    counts = (run if recorded == spikes.shape[0] else network.run(spikes)).counts.numpy()
    scored = Readout.of(ckpt.calibration, ckpt.config, readout).score(
        counts, ckpt.reference_place_ids, query.place_ids, query.truth
    )
    return FloatSide(spikes, recorded, run, counts, scored)


def verify_width(
    bits: int,
    network: VerifiedNetwork,
    query: Query,
    options: VerifyOptions,
    floats: FloatSide,
    folder: Path,
    runtime: Runtime,
    stages: tqdm,
) -> BitsResult:
    """One bit width: deploy, run the integer simulator, read back and run every exported file, read out once,
    compare with float (``stages`` advances by one per stage)."""
    ckpt, device, progress, readout = network.checkpoint, runtime.device, runtime.progress, options.readout
    clock, seconds = time.perf_counter(), {}

    def finished(stage: str, following: str | None = None) -> None:
        """A stage done: its seconds kept, the bar one stage on (showing the following one)."""
        nonlocal clock
        seconds[stage], clock = time.perf_counter() - clock, time.perf_counter()
        stages.update(1)
        if following:
            stages.set_postfix(bits=bits, stage=following)

    stages.set_postfix(bits=bits, stage="quantise")
    model = deploy(ckpt, network.sha256, bits, options.quantise, reference_images=network.reference_images,
                   device=device, progress=progress)  # fmt: skip
    model_path = save_fixed_point(folder / "model.npz", model)
    finished("quantise_and_calibrate", "simulate")
    recorded_spikes = floats.spikes[: floats.recorded]
    int_network = open_backend(model, "integer", device=device, progress=progress)[1]
    int_run = int_network.run(recorded_spikes, record=True)
    int_all = int_run if floats.recorded == floats.spikes.shape[0] else int_network.run(floats.spikes)
    int_counts = int_all.counts.numpy()
    finished("integer_simulator", "targets")
    cross = cross_implementation(model, recorded_spikes, int_run, folder=folder, targets=options.targets,
                                 reference_queries=options.reference_queries, device=device)  # fmt: skip
    cross = with_consumer_gate(cross.with_files("model", [str(model_path)]), model, int_run.raster, recorded_spikes)
    finished("targets_and_reference", "readout")
    scored = Readout.of(model.calibration, model.config, readout).score(
        int_counts, ckpt.reference_place_ids, query.place_ids, floats.scored.truth
    )
    rows = metric_deltas(floats.scored.rows, scored.rows)
    assert floats.run.raster is not None and int_run.raster is not None  # both recorded
    rasters = (floats.run.raster, int_run.raster)
    saturations = model.quantisation.calibration_saturations
    spike = spike_level(*rasters, floats.counts, int_counts, int_all.saturations, saturations)
    decision = decision_level(floats.scored, scored, readout.ks)
    sequences = readout.warning(query.place_ids) is None
    checks = tolerance_checks(rows, spike, decision, options.tolerances, readout.ks, sequences=sequences)
    limits = judged_limits(options.tolerances, (1, *readout.ks), len(query.place_ids), sequences=sequences)
    table = paired_checks(floats.scored.decisions(), scored.decisions(), rows, limits, options.statistics)
    regions = module_regions(len(ckpt.reference_place_ids), ckpt.config.train.module_size)
    group = ckpt.config.network.n_neurons  # neurons per module
    modules = module_rows(regions, group, floats.scored, scored, *rasters) if len(regions) > 1 else ()
    finished("readout")
    return BitsResult(
        bits=bits,
        quantisation=model.quantisation,
        cross_implementation=cross,
        spike_level=spike,
        decision_level=decision,
        metrics=rows,
        tolerance_checks=tuple(checks),
        pr_curves=curves(scored, readout.ks),
        weight_levels=level_histogram(model),
        passed=bits_passed(cross.passed, checks, table),
        seconds={k: round(v, 3) for k, v in seconds.items()},
        modules=modules,
        paired=table,
    )
