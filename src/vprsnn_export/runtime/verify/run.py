"""One float checkpoint verified at every bit width (:func:`verify_checkpoint`): deploy, export, run, check."""

from __future__ import annotations

import dataclasses
import sys
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from vprsnn_export.arguments import require_type
from vprsnn_export.config import Config, VerifyConfig
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.data.truth import Truth
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import DEFAULT_BITS, check_bits, save_fixed_point
from vprsnn_export.export.quantize import DEFAULT_QUANTISE, QuantiseOptions
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.network.cost import query_cost
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.network.modules import module_regions
from vprsnn_export.readout.scoring import Readout
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.targets.intsim import IntegerNetwork
from vprsnn_export.targets.registry import TARGETS

from ..conformance import cross_implementation
from ..consumer_gate import with_consumer_gate
from ..deployment import deploy
from ..results import BitsResult, FloatResult, ModuleRow, VerifiedRun
from .checks import (
    DEFAULT_TOLERANCES,
    curves,
    decision_level,
    level_histogram,
    metric_deltas,
    module_rows,
    spike_level,
    tolerance_checks,
    weight_histograms,
)
from .paired import bits_passed, judged_limits, paired_checks


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

    def to_dict(self, config: Config) -> dict[str, Any]:
        """The settings of a report: the quantisation options beside the bit widths (per_neuron, scale_method,
        fold_thresholds, calibration, non_leaky), the readout with the gamma of ``config`` (the networks' config)."""
        data = dataclasses.asdict(self)
        readout = {"gamma": config.assignment.gamma, **data.pop("readout")}
        return {"readout": readout, "bits": data.pop("bits"), **data.pop("quantise"), **data}


#: Most raster entries (queries x steps x neurons, one byte each) a recorded run may hold: the
#: step-level checks (winner agreement, the exported files' rasters) run on the first queries that
#: fit, the metrics on all of them (a whole route: 2400 queries x 300 steps x 9600 neurons would be
#: 6.9 GB per raster).
RASTER_BUDGET = 1 << 29


def recorded_queries(n_queries: int, timesteps: int, n_neurons: int, budget: int = RASTER_BUDGET) -> int:
    """How many of the first queries the step-level checks record: all, or as many as ``budget`` holds (>= 1)."""
    return int(min(n_queries, max(1, budget // max(1, timesteps * n_neurons))))


def verify_checkpoint(
    ckpt: Checkpoint,
    ckpt_sha256: str,
    query_images: np.ndarray,
    query_place_ids: np.ndarray,
    query_traversal: str,
    options: VerifyOptions,
    *,
    reference_images: Mapping[str, np.ndarray] | None = None,
    export_dir: str | Path | None = None,
    device: torch.device | None = None,
    progress: bool = False,
    label: str | None = None,
    checkpoint: str | None = None,
    truth: Truth | None = None,
) -> VerifiedRun:
    """Quantise ``ckpt`` at every bit width and run every check: one verified run of the report.

    ``reference_images`` (the checkpoint's reference traversals, in its reference place
    order) are needed for the deployed calibration; ``export_dir`` receives each bit
    width's fixed-point model and exported files (a temporary folder when None).
    ``checkpoint`` names the checkpoint's file in the result; ``truth`` judges the queries (None: the readout
    options' match window). Each side is read out once (a :class:`~vprsnn_export.readout.scored.Scored`) and
    every check compares the two.
    """
    require_type("ckpt", ckpt, Checkpoint)
    require_type("options", options, VerifyOptions)
    require_type("options.quantise", options.quantise, QuantiseOptions)
    device = torch.device("cpu") if device is None else device
    bits_list = [check_bits(b) for b in options.bits]
    quantise = options.quantise
    if quantise.calibration == "deployed" and reference_images is None:
        raise InvalidValueError("the deployed calibration needs the reference images")
    readout = options.readout
    query_place_ids = np.asarray(query_place_ids, dtype=np.int64)
    spikes = query_spikes(query_images, query_place_ids, query_traversal, ckpt.config)
    recorded = recorded_queries(spikes.shape[0], spikes.shape[1], ckpt.weights.shape[1], RASTER_BUDGET)
    recorded_spikes = spikes[:recorded]
    float_network = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, ckpt.config, device)
    float_network.progress = progress  # a bar over the query chunks of each network run below
    float_run = float_network.run(recorded_spikes, record=True)
    float_counts = (float_run if recorded == spikes.shape[0] else float_network.run(spikes)).counts.numpy()
    ref_ids = ckpt.reference_place_ids
    regions = module_regions(len(ref_ids), ckpt.config.train.module_size)
    float_scored = Readout.of(ckpt.calibration, ckpt.config, readout).score(
        float_counts, ref_ids, query_place_ids, truth
    )
    sequences = readout.warning(query_place_ids) is None
    limits = judged_limits(options.tolerances, readout.ks, len(query_place_ids), sequences=sequences)
    temporary = tempfile.TemporaryDirectory(prefix="vprsnn-verify-") if export_dir is None else None
    root = Path(temporary.name if temporary is not None else str(export_dir))
    results: list[BitsResult] = []
    desc = f"verify {label or ''}".strip()
    stages = tqdm(total=len(bits_list) * 4, desc=desc, unit="stage", file=sys.stderr, disable=not progress, leave=False)
    try:
        for bits in bits_list:
            clock = time.perf_counter()
            seconds: dict[str, float] = {}
            stages.set_postfix(bits=bits, stage="quantise")
            model = deploy(
                ckpt, ckpt_sha256, bits, quantise, reference_images=reference_images, device=device, progress=progress
            )
            folder = root / f"{bits}bit"
            model_path = save_fixed_point(folder / "model.npz", model)
            seconds["quantise_and_calibrate"], clock = time.perf_counter() - clock, time.perf_counter()
            stages.update(1)
            stages.set_postfix(bits=bits, stage="simulate")
            int_network = IntegerNetwork(model, device, progress=progress)
            int_run = int_network.run(recorded_spikes, record=True)
            int_all = int_run if recorded == spikes.shape[0] else int_network.run(spikes)
            int_counts = int_all.counts.numpy()
            seconds["integer_simulator"], clock = time.perf_counter() - clock, time.perf_counter()
            stages.update(1)
            stages.set_postfix(bits=bits, stage="targets")
            cross = cross_implementation(
                model,
                recorded_spikes,
                int_run,
                folder=folder,
                targets=options.targets,
                reference_queries=options.reference_queries,
                device=device,
            ).with_files("model", [str(model_path)])
            cross = with_consumer_gate(cross, model, int_run.raster, recorded_spikes)
            seconds["targets_and_reference"], clock = time.perf_counter() - clock, time.perf_counter()
            stages.update(1)
            stages.set_postfix(bits=bits, stage="readout")
            scored = Readout.of(model.calibration, model.config, readout).score(
                int_counts, ref_ids, query_place_ids, float_scored.truth
            )
            rows = metric_deltas(float_scored.rows, scored.rows)
            if float_run.raster is None or int_run.raster is None:
                raise InvalidValueError("verify needs the recorded rasters of both networks")
            rasters = (float_run.raster, int_run.raster)
            calibration_saturations = model.quantisation.calibration_saturations
            spike = spike_level(*rasters, float_counts, int_counts, int_all.saturations, calibration_saturations)
            decision = decision_level(float_scored, scored, readout.ks)
            checks = tolerance_checks(rows, spike, decision, options.tolerances, readout.ks, sequences=sequences)
            table = paired_checks(float_scored.decisions(), scored.decisions(), rows, limits, options.statistics)
            modules: tuple[ModuleRow, ...] = ()
            if len(regions) > 1:
                group = ckpt.config.network.n_neurons  # neurons per module
                modules = module_rows(regions, group, float_scored, scored, *rasters)
            seconds["readout"] = time.perf_counter() - clock
            results.append(
                BitsResult(
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
            )
            stages.update(1)
    finally:
        stages.close()
        if temporary is not None:
            temporary.cleanup()
    return VerifiedRun(
        label=label,
        seed=ckpt.config.seed,
        config=ckpt.config.to_dict(),
        checkpoint_sha256=ckpt_sha256,
        checkpoint_data=dict(ckpt.data),
        query=query_traversal,
        n_queries=int(len(query_place_ids)),
        query_place_ids=tuple(int(p) for p in query_place_ids),
        reference_place_ids=tuple(int(p) for p in ref_ids),
        export_dir=None if temporary is not None else str(root),
        float=FloatResult(
            metrics=tuple(float_scored.rows),
            total_spikes=int(float_counts.sum()),
            pr_curves=curves(float_scored, readout.ks),
            weights=weight_histograms(ckpt.weights, quantise.per_neuron),
            cost=query_cost(spikes, ckpt.weights.shape[1], places=len(ref_ids), images=query_images).summary(),
        ),
        bits=tuple(results),
        checkpoint=checkpoint,
        recorded_queries=recorded,
    )
