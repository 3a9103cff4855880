"""From spike counts to the result rows: every strategy at k=1, W+Prob aggregated at each k > 1."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vprsnn_export.dynamics import FloatNetwork
from vprsnn_export.encoding import query_spikes
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.readout.aggregation import VELOCITY_ESTIMATES, aggregate, estimate_velocity, track_velocity
from vprsnn_export.readout.assignment import STRATEGIES, decide, strategy_scores
from vprsnn_export.readout.baseline import sad_distances, sad_distribution
from vprsnn_export.readout.metrics import is_correct, pr_metrics
from vprsnn_export.trainer.calibrate import calibrate


@dataclass(frozen=True)
class ReadoutOptions:
    """How decisions are read out and scored (the CLI's --k, --rule, --velocity, --tolerance)."""

    gamma: float
    ks: tuple[int, ...] = (1,)
    rule: str = "product"
    velocity: float = 1.0
    velocity_candidates: tuple[float, ...] | None = None  # estimate the velocity over this grid instead
    velocity_estimate: str = "window"  # with candidates: "window" (each window alone) or "track" (over the stream)
    velocity_span: int = 10  # "track": windows whose scores are summed before the velocity is chosen
    velocity_length: int | None = None  # "track": frames per scored trajectory (None: 2k)
    velocity_memory: int = 50  # "track": recent frames whose mean is divided out (0: none)
    tolerance: int = 0


def decision_metrics(
    distribution: np.ndarray,
    strategy: str,
    reference_place_ids: np.ndarray,
    query_place_ids: np.ndarray,
    tolerance: int,
) -> dict:
    """Accuracy, P@100R, R@100P, AUC-PR of one score matrix (Q, places)."""
    predicted, confidence = decide(distribution, strategy)
    matched = predicted >= 0
    predicted_ids = np.where(matched, reference_place_ids[np.maximum(predicted, 0)], -1)
    correct = is_correct(predicted_ids, query_place_ids, tolerance) & matched
    return pr_metrics(correct, confidence)


def aggregated(wprob: np.ndarray, k: int, options: ReadoutOptions, frame_positions: np.ndarray | None) -> np.ndarray:
    """W+Prob aggregated over k frames: the given velocity, or one estimated from the query stream.

    With ``velocity_candidates`` the velocity is estimated over that grid, per
    window (``velocity_estimate="window"``) or tracked over the ``velocity_span``
    most recent windows (``"track"``); otherwise ``options.velocity`` is used.
    """
    if options.velocity_candidates and options.velocity_estimate not in VELOCITY_ESTIMATES:
        raise InvalidValueError(
            f"unknown velocity estimate {options.velocity_estimate!r}; choose from {', '.join(VELOCITY_ESTIMATES)}"
        )
    if k == 1:
        return wprob
    if options.velocity_candidates:
        candidates = np.asarray(options.velocity_candidates)
        if options.velocity_estimate == "track":
            _, result = track_velocity(
                wprob,
                k,
                candidates,
                options.velocity_span,
                options.rule,
                frame_positions,
                length=options.velocity_length,
                memory=options.velocity_memory,
            )
            return result
        return estimate_velocity(wprob, k, candidates, options.rule, frame_positions)[1]
    return aggregate(wprob, k, options.velocity, rule=options.rule, frame_positions=frame_positions)


def readout_rows(
    calibration: np.ndarray,
    query_counts: np.ndarray,
    reference_place_ids: np.ndarray,
    query_place_ids: np.ndarray,
    options: ReadoutOptions,
    frame_positions: np.ndarray | None = None,
) -> list[dict]:
    """Rows {strategy, k, accuracy, p_at_100r, r_at_100p, auc_pr, n_queries} for one network."""
    sr = np.asarray(calibration, dtype=np.float64)
    sq = np.asarray(query_counts, dtype=np.float64)
    rows = []
    scores = {s: strategy_scores(sr, sq, s, options.gamma) for s in STRATEGIES}
    for strategy in STRATEGIES:
        metrics = decision_metrics(scores[strategy], strategy, reference_place_ids, query_place_ids, options.tolerance)
        rows.append({"strategy": strategy, "k": 1, **metrics})
    for k in sorted(set(options.ks) - {1}):
        dist = aggregated(scores["wprob"], k, options, frame_positions)
        metrics = decision_metrics(dist, "wprob", reference_place_ids, query_place_ids, options.tolerance)
        rows.append({"strategy": "wprob", "k": k, **metrics})
    return rows


def baseline_rows(
    distribution: np.ndarray,
    reference_place_ids: np.ndarray,
    query_place_ids: np.ndarray,
    options: ReadoutOptions,
    ks: Sequence[int],
    frame_positions: np.ndarray | None = None,
) -> list[dict]:
    """The SAD baseline read out like W+Prob, at every k."""
    rows = []
    for k in sorted(set(ks)):
        dist = aggregated(distribution, k, options, frame_positions)
        metrics = decision_metrics(dist, "wprob", reference_place_ids, query_place_ids, options.tolerance)
        rows.append({"strategy": "sad", "k": k, **metrics})
    return rows


def spike_statistics(candidates_per_step: np.ndarray, counts: np.ndarray) -> dict:
    """How the WTA is exercised: mean |C[t]|, fraction of steps with |C[t]| > 1, spikes per query."""
    candidates = np.asarray(candidates_per_step)
    return {
        "mean_candidates_per_step": float(candidates.mean()),
        "multi_candidate_step_fraction": float((candidates > 1).mean()),
        "quiet_step_fraction": float((candidates == 0).mean()),
        "mean_spikes_per_query": float(np.asarray(counts).sum(axis=1).mean()),
    }


def evaluate_float(
    ckpt,
    query_images: np.ndarray,
    query_place_ids: np.ndarray,
    traversal: str,
    options: ReadoutOptions,
    *,
    device,
    state_isolation: bool | None = None,
    reference_images: dict[str, np.ndarray] | None = None,
) -> dict:
    """Evaluate a float checkpoint on one query traversal: result rows plus spike statistics.

    With ``reference_images`` (the checkpoint's reference traversals, same place order)
    the no-learning SAD baseline is added as rows with strategy "sad".
    """

    network = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, ckpt.config, device)
    run = network.run(
        query_spikes(query_images, query_place_ids, traversal, ckpt.config), state_isolation=state_isolation
    )
    counts = run.counts.numpy()
    reference_ids = ckpt.reference_place_ids
    rows = readout_rows(ckpt.calibration, counts, reference_ids, query_place_ids, options)
    if reference_images is not None:
        reference = np.mean([reference_images[name] for name in ckpt.reference_traversals], axis=0)
        distribution = sad_distribution(sad_distances(reference, query_images))
        rows += baseline_rows(distribution, reference_ids, query_place_ids, options, options.ks)
    return {
        "rows": rows,
        "spike_stats": spike_statistics(run.candidates_per_step.numpy(), counts),
        "query_counts": counts,
    }


def calibrate_and_evaluate(
    network,
    reference_images: dict[str, np.ndarray],
    reference_place_ids: np.ndarray,
    query_images: np.ndarray,
    query_place_ids: np.ndarray,
    query_traversal: str,
    options: ReadoutOptions,
) -> list[dict]:
    """Calibrate any network (``network.counts(spikes)``, ``network.cfg``) and read out the queries."""

    calibration = calibrate(network.counts, reference_images, reference_place_ids, network.cfg)
    counts = network.counts(query_spikes(query_images, query_place_ids, query_traversal, network.cfg)).numpy()
    return readout_rows(calibration, counts, reference_place_ids, query_place_ids, options)
