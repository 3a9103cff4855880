"""Evaluate a float checkpoint or a fixed-point model on a query traversal: run it, hand the counts to its
:class:`~vprsnn_export.readout.scoring.Readout` (every strategy at k=1, the sequence strategy at each k > 1)
and add the no-learning baselines and spike statistics."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
import torch

from vprsnn_export.arguments import check_place_ids, require_type
from vprsnn_export.cluster import Cluster
from vprsnn_export.config import Config
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.network.cost import CostSummary, query_cost
from vprsnn_export.network.dynamics import FloatNetwork, check_run_memory
from vprsnn_export.readout.baseline import (
    cosine_similarities,
    sad_distances,
    sad_distribution,
)
from vprsnn_export.readout.early import early_run, is_off
from vprsnn_export.readout.metrics import MetricRow
from vprsnn_export.readout.regions import ModuleAccuracy, hyperactive_neurons
from vprsnn_export.readout.scoring import (
    Readout,
    baseline_rows,
    nearest_neighbour_rows,
    region_accuracies,
)
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.readout.strategies import SEQUENCE_STRATEGY
from vprsnn_export.targets.intsim import IntegerNetwork, step_agreement
from vprsnn_export.trainer.calibrate import calibrate
from vprsnn_export.trainer.sharded import float_runs_on_cluster

from .deployment import CALIBRATIONS


@dataclass(frozen=True)
class SpikeStatistics:
    """How the WTA is exercised on the queries: mean |C[t]|, steps with |C[t]| > 1 or 0, spikes per query."""

    mean_candidates_per_step: float
    multi_candidate_step_fraction: float
    quiet_step_fraction: float
    mean_spikes_per_query: float

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


def spike_statistics(candidates_per_step: np.ndarray, counts: np.ndarray) -> SpikeStatistics:
    """Statistics of one run: candidates per step (N, T) and spike counts (N, neurons)."""
    candidates = np.asarray(candidates_per_step)
    return SpikeStatistics(
        mean_candidates_per_step=float(candidates.mean()),
        multi_candidate_step_fraction=float((candidates > 1).mean()),
        quiet_step_fraction=float((candidates == 0).mean()),
        mean_spikes_per_query=float(np.asarray(counts).sum(axis=1).mean()),
    )


@dataclass(frozen=True)
class Evaluation:
    """One network evaluated on one query traversal.

    ``rows`` are result rows {strategy, k, accuracy, p_at_100r, r_at_100p, auc_pr, n_queries}
    (plus ``calibration`` for a fixed-point model: its deployed and its float S^R).
    """

    rows: list[dict[str, Any]]
    spike_stats: SpikeStatistics
    query_counts: np.ndarray  # (Q, neurons) int64
    saturations: int = 0
    max_current: int = 0
    winner_agreement: dict[str, float] | None = field(default=None)  # vs the float network, same spikes
    modules: list[ModuleAccuracy] | None = field(default=None)  # an ensemble: per module, W+Prob k=1
    silenced: int | None = None  # an ensemble: neurons silenced by the region regularisation
    cost: CostSummary | None = None  # events per query, SNN vs template (network.cost)

    def to_dict(self) -> dict[str, Any]:
        """The JSON of `evaluate --json` / `simulate --json` (without the spike counts).

        An ensemble adds ``modules`` (per-module accuracy) and ``silenced_neurons``."""
        out: dict[str, Any] = {"results": self.rows, "spike_stats": self.spike_stats.to_dict()}
        if self.winner_agreement is not None:
            out["winner_agreement"] = self.winner_agreement
        if self.modules is not None:
            out["modules"] = [m.to_dict() for m in self.modules]
            out["silenced_neurons"] = self.silenced
        if self.cost is not None:
            out["cost"] = self.cost.to_dict()
        return out


def evaluate_float(
    ckpt: Checkpoint,
    query_images: np.ndarray,
    query_place_ids: np.ndarray,
    traversal: str,
    options: SequenceOptions,
    *,
    device: torch.device | None = None,
    state_isolation: bool | None = None,
    reference_images: Mapping[str, np.ndarray] | None = None,
    cluster: Cluster | None = None,
    progress: bool = False,
) -> Evaluation:
    """Evaluate a float checkpoint on one query traversal: result rows plus spike statistics.

    ``cluster``: the modules' spike counts are computed in tasks there (CPU workers) and gathered
    for the whole-route readout; the same counts bit for bit (:mod:`vprsnn_export.trainer.sharded`).

    With ``reference_images`` (the checkpoint's reference traversals, same place order)
    the no-learning baselines are added: SAD read out like W+Prob (strategy "sad") and the template
    ceiling, cosine nearest neighbour on the same images (strategy "cosine", margin confidence). An ensemble
    (``train.module_size`` > 0) is read out over the whole route with its hyperactive
    neurons silenced (``assignment.hyperactive_share``), and per-module rows are added.
    """
    require_type("ckpt", ckpt, Checkpoint)
    require_type("options", options, SequenceOptions)
    check_run_memory(
        ckpt.config,
        "evaluation",
        presentations=len(check_place_ids(query_place_ids, "query_place_ids")),
        n_neurons=ckpt.weights.shape[1],
        places=len(ckpt.reference_place_ids),
        rasters=0 if _isolated(ckpt.config, state_isolation) else 1,
    )
    device = torch.device("cpu") if device is None else device
    cost = None
    if cluster is not None and not is_off(ckpt.config.early):
        raise InvalidValueError("config.early (the early decision) runs on this machine: not with --cluster")
    if cluster is None:
        network = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, ckpt.config, device)
        network.progress = progress
        spikes = query_spikes(query_images, query_place_ids, traversal, ckpt.config)
        run = network.run(spikes, state_isolation=state_isolation)
        isolated = _isolated(ckpt.config, state_isolation)
        early = early_run(network.run, spikes, ckpt.calibration, ckpt.config, isolated=isolated)  # None: rule off
        if early is not None:
            run = replace(run, counts=torch.from_numpy(early.counts))
        steps = None if early is None else early.steps
        cost = query_cost(
            spikes, ckpt.weights.shape[1], places=len(ckpt.reference_place_ids), images=query_images, steps=steps
        )
    else:
        run = float_runs_on_cluster(
            ckpt.weights,
            ckpt.thresholds,
            ckpt.config,
            {traversal: query_images},
            query_place_ids,
            "query",
            cluster,
            state_isolation=state_isolation,
            progress=progress,
        )[traversal]
    counts = run.counts.numpy()
    reference_ids = ckpt.reference_place_ids
    readout = Readout.of(ckpt.calibration, ckpt.config, options)
    typed, scores, _ = readout.scored(counts, reference_ids, query_place_ids)
    layout = readout.modules
    if reference_images is not None:
        reference = np.mean([reference_images[name] for name in ckpt.reference_traversals], axis=0)
        distribution = sad_distribution(sad_distances(reference, query_images))
        typed += baseline_rows(distribution, reference_ids, query_place_ids, options)
        similarities = cosine_similarities(reference, query_images)
        typed += nearest_neighbour_rows(similarities, "cosine", reference_ids, query_place_ids, options)
    candidates = run.candidates_per_step
    assert candidates is not None  # the float network always reports them
    return Evaluation(
        rows=[row.to_dict() for row in typed],
        spike_stats=spike_statistics(candidates.numpy(), counts),
        query_counts=counts,
        modules=None
        if layout is None
        else region_accuracies(
            scores[SEQUENCE_STRATEGY], reference_ids, query_place_ids, layout.regions, options.tolerance
        ),
        silenced=None if layout is None else int(hyperactive_neurons(ckpt.calibration, layout).sum()),
        cost=None if cost is None else cost.summary(),
    )


def _isolated(cfg: Config, state_isolation: bool | None) -> bool:
    """Whether a run keeps state isolation (the config's setting unless ``state_isolation`` overrides it)."""
    return cfg.network.state_isolation if state_isolation is None else bool(state_isolation)


def evaluate_fixed_point(
    model: FixedPointModel,
    query_images: np.ndarray,
    query_place_ids: np.ndarray,
    traversal: str,
    options: SequenceOptions,
    *,
    device: torch.device | None = None,
    state_isolation: bool | None = None,
    float_checkpoint: Checkpoint | None = None,
    progress: bool = False,
) -> Evaluation:
    """The integer simulator on one query traversal, read out with both calibrations (deployed and float S^R).

    With ``float_checkpoint`` the float network runs on the same spike trains and the
    per-step agreement of the two rasters is added as ``winner_agreement``.
    """
    require_type("model", model, FixedPointModel)
    require_type("options", options, SequenceOptions)
    check_run_memory(
        model.config,
        "evaluation",
        presentations=len(check_place_ids(query_place_ids, "query_place_ids")),
        n_neurons=model.weight_mantissa.shape[1],
        places=len(model.reference_place_ids),
        rasters=(2 if float_checkpoint is not None else 0) + (0 if _isolated(model.config, state_isolation) else 1),
    )
    device = torch.device("cpu") if device is None else device
    spikes = query_spikes(query_images, query_place_ids, traversal, model.config)
    compare = float_checkpoint is not None
    integer = IntegerNetwork(model, device, progress=progress)
    run = integer.run(spikes, record=compare, state_isolation=state_isolation)
    isolated = _isolated(model.config, state_isolation)
    early = early_run(integer.run, spikes, model.calibration, model.config, isolated=isolated)  # None: rule off
    counts = run.counts.numpy() if early is None else early.counts
    rows = []
    for name, calibration in zip(CALIBRATIONS, (model.calibration, model.float_calibration), strict=True):
        readout = Readout.of(calibration, model.config, options)
        for row in readout.rows(counts, model.reference_place_ids, query_place_ids):
            rows.append({"calibration": name, **row.to_dict()})
    agreement = None
    if float_checkpoint is not None and run.raster is not None:
        network = FloatNetwork.from_arrays(float_checkpoint.weights, float_checkpoint.thresholds, model.config, device)
        network.progress = progress
        float_run = network.run(spikes, record=True, state_isolation=state_isolation)
        assert float_run.raster is not None
        agreement = step_agreement(float_run.raster, run.raster)
    assert run.candidates_per_step is not None
    return Evaluation(
        rows=rows,
        spike_stats=spike_statistics(run.candidates_per_step.numpy(), counts),
        query_counts=counts,
        saturations=run.saturations,
        max_current=run.max_current,
        winner_agreement=agreement,
        cost=query_cost(
            spikes,
            model.weight_mantissa.shape[1],
            places=len(model.reference_place_ids),
            images=query_images,
            steps=None if early is None else early.steps,
        ).summary(),
    )


def calibrate_and_evaluate(
    network,
    reference_images: dict[str, np.ndarray],
    reference_place_ids: np.ndarray,
    query_images: np.ndarray,
    query_place_ids: np.ndarray,
    query_traversal: str,
    options: SequenceOptions,
) -> list[MetricRow]:
    """Calibrate any network (``network.counts(spikes)``, ``network.cfg``) and read out the queries."""

    calibration = calibrate(network.counts, reference_images, reference_place_ids, network.cfg)
    counts = network.counts(query_spikes(query_images, query_place_ids, query_traversal, network.cfg)).numpy()
    return Readout.of(calibration, network.cfg, options).rows(counts, reference_place_ids, query_place_ids)
