"""From spike counts to the result rows: every strategy at k=1, W+Prob aggregated at each k > 1."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
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
from vprsnn_export.network.dynamics import FloatNetwork, check_run_memory
from vprsnn_export.readout.aggregation import aggregate
from vprsnn_export.readout.baseline import (
    cosine_similarities,
    diagonal_sums,
    nearest_neighbour,
    sad_distances,
    sad_distribution,
)
from vprsnn_export.readout.metrics import MatchTruth, Tolerance, is_correct, pr_metrics, predicted_place_ids
from vprsnn_export.readout.regions import (
    ModuleAccuracy,
    ModuleLayout,
    hyperactive_neurons,
    module_accuracy,
    module_layout,
    regularise,
)
from vprsnn_export.readout.strategies import SEQUENCE_STRATEGY, STRATEGIES, all_scores, decide
from vprsnn_export.readout.velocity import DEFAULT_VELOCITY_ESTIMATE, VELOCITY_ESTIMATES, VelocitySettings
from vprsnn_export.targets.intsim import IntegerNetwork, step_agreement
from vprsnn_export.trainer.calibrate import calibrate
from vprsnn_export.trainer.sharded import float_runs_on_cluster

from .results import MetricRow


@dataclass(frozen=True)
class ReadoutOptions:
    """How decisions are read out and scored (the CLI's --k, --rule, --velocity, --match-window).

    ``tolerance`` is the ground-truth window in places: a prediction within +-tolerance of the
    true place counts as correct (0 = exact match); or the data set's ground truth (a MatchTruth).
    """

    gamma: float
    ks: tuple[int, ...] = (1,)
    rule: str = "product"
    velocity: float = 1.0
    velocity_candidates: tuple[float, ...] | None = None  # estimate the velocity over this grid instead
    # with candidates: a registered estimator (readout.velocity): "smooth" (track with a fixed lag; the default),
    # "track" (over the stream) or "window" (each window alone)
    velocity_estimate: str = DEFAULT_VELOCITY_ESTIMATE
    velocity_span: int = 10  # "track", "smooth": windows whose scores are summed before the velocity is chosen
    velocity_length: int | None = None  # "track", "smooth": frames per scored trajectory (None: 2k, 3k)
    velocity_memory: int = 50  # "track", "smooth": recent frames whose mean is divided out (0: none)
    velocity_lag: int | None = None  # "smooth": frames each decision waits for (None: 2k - 1)
    tolerance: Tolerance = 0

    @classmethod
    def from_config(cls, config: Config, **settings: Any) -> ReadoutOptions:
        """The options of a network trained with ``config``: gamma is the config's ``assignment.gamma`` (its one
        source; every caller that reads out a checkpoint or model takes it from here), the rest as given."""
        require_type("config", config, Config)
        return cls(gamma=config.assignment.gamma, **settings)

    def with_config(self, config: Config) -> ReadoutOptions:
        """These options for a network trained with ``config`` (its ``assignment.gamma``)."""
        require_type("config", config, Config)
        return replace(self, gamma=config.assignment.gamma)


def decision_metrics(
    distribution: np.ndarray,
    strategy: str,
    reference_place_ids: np.ndarray,
    query_place_ids: np.ndarray,
    tolerance: Tolerance,
) -> dict:
    """Accuracy, P@100R, R@100P, AUC-PR of one score matrix (Q, places)."""
    predicted, confidence = decide(distribution, strategy)
    correct = is_correct(predicted_place_ids(predicted, reference_place_ids), query_place_ids, tolerance)
    return pr_metrics(correct, confidence)


def aggregated(wprob: np.ndarray, k: int, options: ReadoutOptions, frame_positions: np.ndarray | None) -> np.ndarray:
    """W+Prob aggregated over k frames: the given velocity, or one estimated from the query stream.

    With ``velocity_candidates`` the velocity is estimated over that grid by the registered
    estimator ``velocity_estimate`` (``readout.velocity.VELOCITY_ESTIMATES``): per window
    (``"window"``), tracked over the ``velocity_span`` most recent windows (``"track"``) or over
    those and the next ``velocity_lag`` windows (``"smooth"``, the default); otherwise
    ``options.velocity`` is used.
    """
    estimator = VELOCITY_ESTIMATES.get(options.velocity_estimate) if options.velocity_candidates else None
    if k == 1:
        return wprob
    if estimator is not None and options.velocity_candidates:
        settings = VelocitySettings(
            rule=options.rule,
            span=options.velocity_span,
            length=options.velocity_length,
            memory=options.velocity_memory,
            lag=options.velocity_lag,
        )
        return estimator.estimate(wprob, k, np.asarray(options.velocity_candidates), frame_positions, settings)[1]
    return aggregate(wprob, k, options.velocity, rule=options.rule, frame_positions=frame_positions)


def check_sequence_length(options: ReadoutOptions, n_queries: int) -> None:
    """InvalidValueError when a sequence length k exceeds the number of queries (no full window exists)."""
    if max(options.ks) > n_queries:
        raise InvalidValueError(f"--k {max(options.ks)} exceeds the number of queries ({n_queries})")


def sequence_warning(query_place_ids: np.ndarray, options: ReadoutOptions) -> str | None:
    """A warning when sequence aggregation is asked for on queries that are not consecutive places.

    Aggregation assumes the query stream is a traversal (consecutive place ids, in order, at the
    velocity); on a subset spread along the route its windows mix unrelated places.
    """
    ids = np.asarray(query_place_ids)
    if max(options.ks) <= 1 or ids.size < 2:
        return None
    steps = np.diff(ids)
    if np.all(np.abs(steps) <= 2):
        return None
    share = float(np.mean(np.abs(steps) > 2))
    return (
        f"sequence aggregation (k up to {max(options.ks)}) on queries that are not consecutive places: "
        f"{100 * share:.0f} % of successive queries are more than 2 places apart, so the k-frame windows "
        "mix unrelated places"
    )


def check_places_overlap(reference_place_ids: np.ndarray, query_place_ids: np.ndarray, tolerance: Tolerance) -> None:
    """InvalidValueError when no query place lies within ``tolerance`` of a reference place (or, with a
    ground truth, no query matches a reference place): every decision would be wrong by construction
    (the model was trained on other places)."""
    reference = np.sort(np.asarray(reference_place_ids, dtype=np.int64))
    queries = np.asarray(query_place_ids, dtype=np.int64)
    if reference.size == 0 or queries.size == 0:
        return
    if isinstance(tolerance, MatchTruth):
        n_reference, n_query = tolerance.matrix.shape
        if queries.min() < 0 or queries.max() >= n_query:
            raise InvalidValueError(f"query place ids outside the ground truth's 0..{n_query - 1} ({tolerance.source})")
        inside = reference[reference < n_reference]
        if not tolerance.matrix[np.ix_(inside, queries)].any():
            raise InvalidValueError(
                f"none of the {queries.size} queries matches one of the model's {reference.size} reference places "
                f"by the ground truth {tolerance.source}: select the places it was trained on (--places / --subset)"
            )
        return
    nearest = np.clip(np.searchsorted(reference, queries), 0, reference.size - 1)
    below = reference[np.clip(nearest - 1, 0, reference.size - 1)]
    gap = np.minimum(np.abs(reference[nearest] - queries), np.abs(below - queries))
    if np.all(gap > tolerance):
        raise InvalidValueError(
            f"none of the {queries.size} query places ({queries.min()}..{queries.max()}) is among the model's "
            f"{reference.size} reference places ({reference[0]}..{reference[-1]}): select the places it was "
            "trained on (--places / --subset)"
        )


def readout_scores(
    calibration: np.ndarray, query_counts: np.ndarray, gamma: float, modules: ModuleLayout | None = None
) -> dict[str, np.ndarray]:
    """The k=1 scores of every registered strategy (``readout.strategies.STRATEGIES``), (Q, places) each.

    With ``modules`` (an ensemble) the hyperactive neurons are silenced first
    (``readout.regions.regularise``: decided from S^R alone). The weighted scores are computed once
    and W+Prob is derived from them (:func:`~vprsnn_export.readout.strategies.all_scores`).
    """
    sr, sq = regularise(calibration, query_counts, modules)
    return all_scores(sr, sq, gamma)


def check_readout_arrays(
    calibration: np.ndarray, query_counts: np.ndarray, reference_place_ids: np.ndarray, query_place_ids: np.ndarray
) -> None:
    """S^R (neurons, places) with one column per reference id and S^Q (queries, neurons) with one row per query
    id; InvalidValueError naming the argument that does not fit (else decisions would name the wrong places)."""
    shapes = {name: np.shape(value) for name, value in (("calibration", calibration), ("query_counts", query_counts))}
    ids = {"reference_place_ids": np.shape(reference_place_ids), "query_place_ids": np.shape(query_place_ids)}
    for name, shape in {**shapes, **ids}.items():
        if len(shape) != (2 if name in shapes else 1):
            raise InvalidValueError(f"{name} has shape {shape}, expected {2 if name in shapes else 1}-D")
    if shapes["calibration"][1] != ids["reference_place_ids"][0]:
        raise InvalidValueError(
            f"calibration covers {shapes['calibration'][1]} places but reference_place_ids names "
            f"{ids['reference_place_ids'][0]}"
        )
    if shapes["query_counts"] != (ids["query_place_ids"][0], shapes["calibration"][0]):
        raise InvalidValueError(
            f"query_counts has shape {shapes['query_counts']}, expected ({ids['query_place_ids'][0]}, "
            f"{shapes['calibration'][0]}): one row per query id, one column per neuron of the calibration"
        )


def readout_rows(
    calibration: np.ndarray,
    query_counts: np.ndarray,
    reference_place_ids: np.ndarray,
    query_place_ids: np.ndarray,
    options: ReadoutOptions,
    frame_positions: np.ndarray | None = None,
    *,
    modules: ModuleLayout | None = None,
) -> list[MetricRow]:
    """The typed rows (strategy, k, accuracy, P@100R, R@100P, AUC-PR, number of queries) of one network.

    ``modules``: the layout of an ensemble, whose hyperactive neurons are silenced (None: no regularisation).
    """
    require_type("options", options, ReadoutOptions)
    check_readout_arrays(calibration, query_counts, reference_place_ids, query_place_ids)
    check_sequence_length(options, len(query_place_ids))
    check_places_overlap(reference_place_ids, query_place_ids, options.tolerance)
    scores = readout_scores(calibration, query_counts, options.gamma, modules)
    return score_rows(scores, reference_place_ids, query_place_ids, options, frame_positions)


def score_rows(
    scores: Mapping[str, np.ndarray],
    reference_place_ids: np.ndarray,
    query_place_ids: np.ndarray,
    options: ReadoutOptions,
    frame_positions: np.ndarray | None = None,
) -> list[MetricRow]:
    """The rows of :func:`readout_rows` from the scores of :func:`readout_scores`."""
    rows = []
    for strategy in STRATEGIES:
        metrics = decision_metrics(scores[strategy], strategy, reference_place_ids, query_place_ids, options.tolerance)
        rows.append(metric_row(strategy, 1, metrics))
    for k in sorted(set(options.ks) - {1}):
        dist = aggregated(scores[SEQUENCE_STRATEGY], k, options, frame_positions)
        metrics = decision_metrics(dist, SEQUENCE_STRATEGY, reference_place_ids, query_place_ids, options.tolerance)
        rows.append(metric_row(SEQUENCE_STRATEGY, k, metrics))
    return rows


def metric_row(strategy: str, k: int, metrics: Mapping[str, Any]) -> MetricRow:
    """The typed row of one readout from :func:`~vprsnn_export.readout.metrics.pr_metrics`' values."""
    return MetricRow.from_dict({"strategy": strategy, "k": k, **metrics})


def ensemble_layout(config: Config, n_places: int) -> ModuleLayout | None:
    """The module layout of an ensemble's config (None for a single network, ``train.module_size`` 0)."""
    return module_layout(config, n_places) if config.train.module_size > 0 else None


def module_accuracies(
    wprob: np.ndarray,
    reference_place_ids: np.ndarray,
    query_place_ids: np.ndarray,
    modules: ModuleLayout,
    tolerance: Tolerance = 0,
) -> list[ModuleAccuracy]:
    """Per module: accuracy and in-region share of the whole-route W+Prob (k=1) decisions on its region's queries."""
    predicted, _ = decide(wprob, "wprob")
    correct = is_correct(predicted_place_ids(predicted, reference_place_ids), query_place_ids, tolerance)
    return module_accuracy(predicted, correct, reference_place_ids, query_place_ids, modules.regions)


def baseline_rows(
    distribution: np.ndarray,
    reference_place_ids: np.ndarray,
    query_place_ids: np.ndarray,
    options: ReadoutOptions,
    ks: Sequence[int],
    frame_positions: np.ndarray | None = None,
) -> list[MetricRow]:
    """The SAD baseline read out like W+Prob, at every k."""
    rows = []
    for k in sorted(set(ks)):
        dist = aggregated(distribution, k, options, frame_positions)
        metrics = decision_metrics(dist, "wprob", reference_place_ids, query_place_ids, options.tolerance)
        rows.append(metric_row("sad", k, metrics))
    return rows


def nearest_neighbour_rows(
    similarities: np.ndarray,
    name: str,
    reference_place_ids: np.ndarray,
    query_place_ids: np.ndarray,
    options: ReadoutOptions,
    ks: Sequence[int],
    frame_positions: np.ndarray | None = None,
) -> list[MetricRow]:
    """A no-learning baseline read out as nearest neighbour at every k: the best place, the margin between
    the best and second-best score as confidence, k frames summed along the diagonal at the given velocity
    (:func:`vprsnn_export.readout.baseline.diagonal_sums`). Rows with strategy ``name``."""
    rows = []
    for k in sorted(set(ks)):
        summed = diagonal_sums(similarities, k, options.velocity, frame_positions)
        predicted, confidence = nearest_neighbour(summed)
        correct = is_correct(predicted_place_ids(predicted, reference_place_ids), query_place_ids, options.tolerance)
        rows.append(metric_row(name, k, pr_metrics(correct, confidence)))
    return rows


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

    def to_dict(self) -> dict[str, Any]:
        """The JSON of `evaluate --json` / `simulate --json` (without the spike counts).

        An ensemble adds ``modules`` (per-module accuracy) and ``silenced_neurons``."""
        out: dict[str, Any] = {"results": self.rows, "spike_stats": self.spike_stats.to_dict()}
        if self.winner_agreement is not None:
            out["winner_agreement"] = self.winner_agreement
        if self.modules is not None:
            out["modules"] = [m.to_dict() for m in self.modules]
            out["silenced_neurons"] = self.silenced
        return out


def evaluate_float(
    ckpt: Checkpoint,
    query_images: np.ndarray,
    query_place_ids: np.ndarray,
    traversal: str,
    options: ReadoutOptions,
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
    require_type("options", options, ReadoutOptions)
    check_run_memory(
        ckpt.config,
        "evaluation",
        presentations=len(check_place_ids(query_place_ids, "query_place_ids")),
        n_neurons=ckpt.weights.shape[1],
        places=len(ckpt.reference_place_ids),
        rasters=0 if _isolated(ckpt.config, state_isolation) else 1,
    )
    device = torch.device("cpu") if device is None else device
    if cluster is None:
        network = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, ckpt.config, device)
        network.progress = progress
        run = network.run(
            query_spikes(query_images, query_place_ids, traversal, ckpt.config), state_isolation=state_isolation
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
    layout = ensemble_layout(ckpt.config, len(reference_ids))
    check_readout_arrays(ckpt.calibration, counts, reference_ids, query_place_ids)
    check_sequence_length(options, len(query_place_ids))
    check_places_overlap(reference_ids, query_place_ids, options.tolerance)
    scores = readout_scores(ckpt.calibration, counts, options.gamma, layout)
    typed = score_rows(scores, reference_ids, query_place_ids, options)
    if reference_images is not None:
        reference = np.mean([reference_images[name] for name in ckpt.reference_traversals], axis=0)
        distribution = sad_distribution(sad_distances(reference, query_images))
        typed += baseline_rows(distribution, reference_ids, query_place_ids, options, options.ks)
        similarities = cosine_similarities(reference, query_images)
        typed += nearest_neighbour_rows(similarities, "cosine", reference_ids, query_place_ids, options, options.ks)
    candidates = run.candidates_per_step
    assert candidates is not None  # the float network always reports them
    return Evaluation(
        rows=[row.to_dict() for row in typed],
        spike_stats=spike_statistics(candidates.numpy(), counts),
        query_counts=counts,
        modules=None
        if layout is None
        else module_accuracies(scores["wprob"], reference_ids, query_place_ids, layout, options.tolerance),
        silenced=None if layout is None else int(hyperactive_neurons(ckpt.calibration, layout).sum()),
    )


CALIBRATIONS = ("deployed", "float")


def _isolated(cfg: Config, state_isolation: bool | None) -> bool:
    """Whether a run keeps state isolation (the config's setting unless ``state_isolation`` overrides it)."""
    return cfg.network.state_isolation if state_isolation is None else bool(state_isolation)


def evaluate_fixed_point(
    model: FixedPointModel,
    query_images: np.ndarray,
    query_place_ids: np.ndarray,
    traversal: str,
    options: ReadoutOptions,
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
    require_type("options", options, ReadoutOptions)
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
    run = IntegerNetwork(model, device, progress=progress).run(spikes, record=compare, state_isolation=state_isolation)
    counts = run.counts.numpy()
    rows = []
    layout = ensemble_layout(model.config, len(model.reference_place_ids))
    for name, calibration in zip(CALIBRATIONS, (model.calibration, model.float_calibration), strict=True):
        for row in readout_rows(
            calibration, counts, model.reference_place_ids, query_place_ids, options, modules=layout
        ):
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
    )


def calibrate_and_evaluate(
    network,
    reference_images: dict[str, np.ndarray],
    reference_place_ids: np.ndarray,
    query_images: np.ndarray,
    query_place_ids: np.ndarray,
    query_traversal: str,
    options: ReadoutOptions,
) -> list[MetricRow]:
    """Calibrate any network (``network.counts(spikes)``, ``network.cfg``) and read out the queries."""

    calibration = calibrate(network.counts, reference_images, reference_place_ids, network.cfg)
    counts = network.counts(query_spikes(query_images, query_place_ids, query_traversal, network.cfg)).numpy()
    layout = ensemble_layout(network.cfg, len(reference_place_ids))
    return readout_rows(calibration, counts, reference_place_ids, query_place_ids, options, modules=layout)
