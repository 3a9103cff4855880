"""Evaluate a float checkpoint or a fixed-point model on a query traversal: encode the queries, run them on
the network's backend from the registry (:mod:`vprsnn_export.runtime.backends`), hand the counts to its
:class:`~vprsnn_export.readout.scoring.Readout` (every strategy at k=1, the sequence strategy at each k > 1)
and add the no-learning baselines and spike statistics."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any, TypeVar

import numpy as np
import torch
from scipy import sparse
from tqdm import tqdm

from vprsnn_export.arguments import check_place_ids, require_type
from vprsnn_export.cluster import Cluster
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.data.truth import Truth, window
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.export.quantize import CALIBRATIONS
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.io.serial import JsonDataclass, json_options
from vprsnn_export.network.cost import CostSummary, joined_costs, query_cost
from vprsnn_export.network.dynamics import check_run_memory
from vprsnn_export.network.runs import SpikeRun, joined_runs
from vprsnn_export.readout.baseline import cosine_similarities, sad_distances, sad_distribution
from vprsnn_export.readout.early import early_queries, is_off
from vprsnn_export.readout.metrics import MetricRow
from vprsnn_export.readout.regions import ModuleAccuracy, hyperactive_neurons
from vprsnn_export.readout.scored import Scored
from vprsnn_export.readout.scoring import READOUT_BLOCK, Readout, baseline_rows, nearest_neighbour_rows
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.readout.strategies import STRATEGIES
from vprsnn_export.targets.intsim import step_agreement
from vprsnn_export.trainer.calibrate import DENSE_COUNT_ENTRIES, calibrate
from vprsnn_export.trainer.sharded import float_runs_on_cluster

from .backends import Network, choose_backend, open_backend

NOT_WRITTEN = json_options(write=False)
NetworkT = TypeVar("NetworkT", Checkpoint, FixedPointModel)
#: The queries of a long route run at once, their counts then kept as CSR (:func:`_run_queries`).
LONG_ROUTE_BLOCK = 1024


@dataclass(frozen=True)
class SpikeStatistics(JsonDataclass):
    """How the WTA is exercised on the queries: mean |C[t]|, steps with |C[t]| > 1 or 0, spikes per query."""

    mean_candidates_per_step: float
    multi_candidate_step_fraction: float
    quiet_step_fraction: float
    mean_spikes_per_query: float


def spike_statistics(run: SpikeRun, counts: np.ndarray | sparse.csr_array) -> SpikeStatistics:
    """Statistics of one run: its candidates per step (N, T) and its spike counts (N, neurons), dense or CSR."""
    if run.candidates_per_step is None:
        raise InvalidValueError("this backend does not report candidates per step: evaluate needs them")
    candidates = run.candidates_per_step.numpy()
    return SpikeStatistics(
        mean_candidates_per_step=float(candidates.mean()),
        multi_candidate_step_fraction=float((candidates > 1).mean()),
        quiet_step_fraction=float((candidates == 0).mean()),
        mean_spikes_per_query=float(np.asarray(counts.sum(axis=1)).mean()),
    )


@dataclass(frozen=True)
class Evaluation(JsonDataclass):
    """One network evaluated on one query traversal; its JSON is that of `evaluate --json` / `simulate --json`
    (without the spike counts; an ensemble adds ``modules``, per-module accuracy, and ``silenced_neurons``).

    ``rows`` are result rows {strategy, k, accuracy, p_at_100r, r_at_100p, auc_pr, n_queries}
    (plus ``calibration`` for a fixed-point model: its deployed and its float S^R).
    """

    rows: list[dict[str, Any]] = field(metadata=json_options(key="results"))
    spike_stats: SpikeStatistics
    # (Q, neurons) int64; CSR on a long route (_run_queries, or gathered from a cluster)
    query_counts: np.ndarray | sparse.csr_array = field(metadata=NOT_WRITTEN)
    saturations: int = field(default=0, metadata=NOT_WRITTEN)
    max_current: int = field(default=0, metadata=NOT_WRITTEN)
    # vs the float network, same spikes
    winner_agreement: dict[str, float] | None = field(default=None, metadata=json_options(omit="none"))
    # an ensemble: per module, W+Prob k=1
    modules: list[ModuleAccuracy] | None = field(default=None, metadata=json_options(omit="none"))
    # an ensemble: neurons silenced by the region regularisation
    silenced: int | None = field(
        default=None, metadata=json_options(key="silenced_neurons", omit=lambda e: e.modules is None)
    )
    cost: CostSummary | None = field(default=None, metadata=json_options(omit="none"))  # events per query
    # every readout column of the network's own S^R
    scored: Scored | None = field(default=None, repr=False, metadata=NOT_WRITTEN)


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
    backend: str = "auto",
    truth: Truth | None = None,
) -> Evaluation:
    """Evaluate a float checkpoint on one query traversal: result rows plus spike statistics.

    The counts come from ``backend`` of :data:`~vprsnn_export.runtime.backends.BACKENDS` (``auto``: the float
    network), or with ``cluster`` from the float network's modules run in tasks there (the same counts bit for
    bit, :mod:`vprsnn_export.trainer.sharded`). ``reference_images`` (the reference traversals, same place order)
    add the no-learning baselines: SAD read out like W+Prob ("sad") and cosine nearest neighbour ("cosine"). An
    ensemble is read out over the whole route with its hyperactive neurons silenced, and per-module rows are
    added. ``truth`` judges the queries (None: the options' match window).
    """
    require_type("ckpt", ckpt, Checkpoint)
    require_type("options", options, SequenceOptions)
    network, block = _prepared(ckpt, query_place_ids, state_isolation, options)
    cost = None
    if cluster is None:
        run, counts, cost, _ = _run_queries(
            network, query_images, query_place_ids, traversal, backend, device=device, progress=progress
        )
    elif not is_off(ckpt.config.early):
        raise InvalidValueError("config.early (the early decision) runs on this machine: not with --cluster")
    elif choose_backend(ckpt, backend).name != "float":
        raise InvalidValueError(f"--cluster runs the float network, not the backend {backend}")
    else:
        images = {traversal: query_images}
        gathered = float_runs_on_cluster(
            ckpt.weights, ckpt.thresholds, network.config, images, query_place_ids, "query", cluster, progress=progress
        )[traversal]
        # CSR where the local run keeps CSR (a long route), else dense: the same counts either way
        long_route = sparse_query_counts(network, len(query_place_ids))
        counts = gathered.counts if long_route else gathered.counts.toarray()
        no_counts = torch.zeros((len(query_place_ids), 0), dtype=torch.int64)  # the counts are ``counts``
        run = SpikeRun(no_counts, torch.from_numpy(gathered.candidates_per_step))
    reference_ids = ckpt.reference_place_ids
    readout = Readout.of(ckpt.calibration, ckpt.config, options)
    truth = window(options.tolerance) if truth is None else truth
    scored = read_out(readout, counts, reference_ids, query_place_ids, truth, progress=progress, block=block)
    typed, layout = scored.rows, readout.modules
    if reference_images is not None:
        reference = np.mean([reference_images[name] for name in ckpt.reference_traversals], axis=0)
        distribution = sad_distribution(sad_distances(reference, query_images))
        typed += baseline_rows(distribution, reference_ids, query_place_ids, options, truth)
        similarities = cosine_similarities(reference, query_images)
        typed += nearest_neighbour_rows(similarities, "cosine", reference_ids, query_place_ids, options, truth)
    return Evaluation(
        rows=[row.to_dict() for row in typed],
        spike_stats=spike_statistics(run, counts),
        query_counts=counts,
        modules=None if layout is None else scored.regions(layout.regions),
        silenced=None if layout is None else int(hyperactive_neurons(ckpt.calibration, layout).sum()),
        cost=cost,
        scored=scored,
    )


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
    backend: str = "auto",
    truth: Truth | None = None,
) -> Evaluation:
    """A fixed-point model on one query traversal, read out with both calibrations (deployed and float S^R).

    The counts come from ``backend`` of :data:`~vprsnn_export.runtime.backends.BACKENDS` (``auto``: the
    integer simulator). With ``float_checkpoint`` the float network runs on the same spike trains and the
    per-step agreement of the two rasters is added as ``winner_agreement``.
    """
    require_type("model", model, FixedPointModel)
    require_type("options", options, SequenceOptions)
    compare = float_checkpoint is not None
    network, block = _prepared(model, query_place_ids, state_isolation, options, rasters=2 * compare)
    run, counts, cost, spikes = _run_queries(
        network, query_images, query_place_ids, traversal, backend, device=device, progress=progress, record=compare
    )
    rows, sides = [], []
    for name, calibration in zip(CALIBRATIONS, (model.calibration, model.float_calibration), strict=True):
        readout = Readout.of(calibration, model.config, options)
        sides.append(read_out(readout, counts, model.reference_place_ids, query_place_ids, truth, progress, block))
        rows += [{"calibration": name, **row.to_dict()} for row in sides[-1].rows]
    agreement = None
    if float_checkpoint is not None and run.raster is not None and spikes is not None:  # recorded: never blocks
        float_network = replace(float_checkpoint, config=network.config)
        float_run = open_backend(float_network, "float", device=device, progress=progress)[1].run(spikes, record=True)
        assert float_run.raster is not None
        agreement = step_agreement(float_run.raster, run.raster)
    return Evaluation(
        rows=rows,
        spike_stats=spike_statistics(run, counts),
        query_counts=counts,
        saturations=run.saturations,
        max_current=run.max_current,
        winner_agreement=agreement,
        cost=cost,
        scored=sides[0],
    )


def read_out(
    readout: Readout,
    counts: np.ndarray,
    reference_ids: np.ndarray,
    query_ids: np.ndarray,
    truth: Truth | None,
    progress: bool = False,
    block: int = READOUT_BLOCK,
) -> Scored:
    """The queries read out: in blocks of ``block`` queries when there are more (the same columns bit for bit,
    without a (queries x places) matrix), else whole; a velocity searched over the stream looks ahead, so it is
    read out whole."""
    if len(query_ids) > block and readout.options.velocity_candidates is None:
        return readout.score_in_blocks(counts, reference_ids, query_ids, truth, block=block, progress=progress)
    return readout.score(counts, reference_ids, query_ids, truth)


#: The readout blocks an evaluation tries, largest first, until its memory need fits the limit (:func:`_prepared`).
READOUT_BLOCKS = tuple(READOUT_BLOCK >> halving for halving in range(5))


def _prepared(
    network: NetworkT, place_ids: np.ndarray, state_isolation: bool | None, options: SequenceOptions, rasters: int = 0
) -> tuple[NetworkT, int]:
    """The network with ``state_isolation`` (None: its config's own) in its config, as its backend runs it, and the
    largest readout block of :data:`READOUT_BLOCKS` whose run fits the memory limit (``rasters`` recorded, one more
    without state isolation; the readout a block and its history at a time, :func:`read_out`); InvalidValueError
    when the run would not fit even with the smallest."""
    if state_isolation is not None:
        network = replace(network, config=network.config.replace(**{"network.state_isolation": bool(state_isolation)}))
    sizes = {
        "presentations": len(check_place_ids(place_ids, "query_place_ids")),
        "n_neurons": network.calibration.shape[0],
        "places": len(network.reference_place_ids),
        "rasters": rasters + (0 if network.config.network.state_isolation else 1),
        "readout_arrays": len(STRATEGIES.names()) + len(options.ks) + 2,
        "block": LONG_ROUTE_BLOCK if sparse_query_counts(network, len(place_ids), rasters > 0) else None,
    }
    check = partial(check_run_memory, network.config, "evaluation", **sizes)
    if options.velocity_candidates is not None:  # read out whole
        check(readout_rows=None)
        return network, READOUT_BLOCK
    *larger, smallest = READOUT_BLOCKS
    for block in larger:
        with contextlib.suppress(InvalidValueError):
            check(readout_rows=block + max(options.ks))
            return network, block
    check(readout_rows=smallest + max(options.ks))  # the smallest need's error when even that does not fit
    return network, smallest


def _run_queries(
    network: Network,
    images: np.ndarray,
    place_ids: np.ndarray,
    traversal: str,
    backend: str,
    *,
    device: torch.device | None,
    progress: bool,
    record: bool = False,
) -> tuple[SpikeRun, np.ndarray | sparse.csr_array, CostSummary, torch.Tensor | None]:
    """Encode the queries and run them on the registry's ``backend`` for this network: (the run, its counts
    (``config.early``'s when that rule is on), its cost per query, the spike trains). A long route
    (:func:`sparse_query_counts`) is encoded and run :data:`LONG_ROUTE_BLOCK` queries at a time, its counts
    kept as an int64 CSR array: the same counts and cost (each query has its own seed and starts from V = 0),
    without the whole route's spike trains (None) or a dense (queries, neurons) array."""
    long_route = sparse_query_counts(network, len(place_ids), record)
    runner = open_backend(network, backend, device=device, progress=progress and not long_route)[1]
    places = len(network.reference_place_ids)
    if long_route:
        runs, blocks, costs = [], [], []
        with tqdm(
            total=len(place_ids), desc=runner.name, unit="query", file=sys.stderr, leave=False, disable=not progress
        ) as bar:
            for start in range(0, len(place_ids), LONG_ROUTE_BLOCK):
                block = slice(start, start + LONG_ROUTE_BLOCK)
                spikes = query_spikes(images[block], place_ids[block], traversal, network.config)
                run = runner.run(spikes)
                blocks.append(sparse.csr_array(run.counts.numpy().astype(np.int64)))
                # the joined run keeps no counts (N, 0), final voltages or W+Prob rows, each (queries, neurons or
                # places): 2.9 GB of float32 voltages at 27k
                runs.append(replace(run, counts=run.counts[:, :0].clone(), final_voltage=None, wprob=None))
                costs.append(query_cost(spikes, int(run.counts.shape[1]), places=places, images=images[block]))
                bar.update(len(spikes))
        return joined_runs(runs), sparse.vstack(blocks, format="csr"), joined_costs(costs).summary(), None
    spikes = query_spikes(images, place_ids, traversal, network.config)
    steps = None
    if is_off(network.config.early):
        run = runner.run(spikes, record=record)
    else:  # each chunk run once: the rule's counts, and the whole presentations' candidates and saturations
        parts, early = early_queries(runner.run, spikes, network.calibration, network.config, keep_raster=record)
        run, steps = replace(joined_runs(parts), counts=torch.from_numpy(early.counts)), early.steps
    cost = query_cost(spikes, int(run.counts.shape[1]), places=places, images=images, steps=steps)
    return run, run.counts.numpy(), cost.summary(), spikes


def sparse_query_counts(network: Network, queries: int, record: bool = False) -> bool:
    """Whether :func:`_run_queries` runs a long route in blocks with its counts as CSR: more than
    :data:`~vprsnn_export.trainer.calibrate.DENSE_COUNT_ENTRIES` queries x neurons, each query from V = 0
    (state isolation), no early decision and no raster recorded."""
    config = network.config
    big = queries * int(network.calibration.shape[0]) > DENSE_COUNT_ENTRIES
    return big and config.network.state_isolation and is_off(config.early) and not record


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
