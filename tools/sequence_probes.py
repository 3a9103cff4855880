"""Where the whole route's k=5 gap to cosine lies (issue 34; research log §14).

From the cached counts of ``tools/route_diagnose.py`` (its ``--cache`` file of a checkpoint: S^R and the query counts),
read out W+Prob and report, in %:

* the sequence aggregation with other product-rule floors ``eps`` and the sum rule (velocity 1, exact match);
* the rank of the true place in each frame's distribution (top 1 / 5 / 20 / 100), beside cosine's on the same images;
* with ``--calibration-timesteps T``, S^R recomputed at a longer window T (queries as cached).

    python tools/sequence_probes.py CKPT CACHE.npz --data ../shared/data/nordland_64x32_summer_winter \
        [--query winter] [--calibration-timesteps 900] [--threads 2]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

import vprsnn_export as vx
from vprsnn_export.data.encoding import calibration_spikes
from vprsnn_export.readout.aggregation import aggregate
from vprsnn_export.readout.baseline import cosine_similarities
from vprsnn_export.readout.metrics import is_correct, pr_metrics, predicted_place_ids
from vprsnn_export.readout.scoring import Readout
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.readout.strategies import decide

KS = (1, 5, 10)
RANKS = (1, 5, 20, 100)


def metrics(dist: np.ndarray, ids: np.ndarray) -> str:
    """W+Prob accuracy / R@100P in % of an aggregated distribution (exact match, reference order = query order)."""
    pred, conf = decide(dist, "wprob")
    m = pr_metrics(is_correct(predicted_place_ids(pred, ids), ids, 0), conf)
    return f"{100 * m['accuracy']:.1f} / {100 * m['r_at_100p']:.1f}"


def true_rank_shares(scores: np.ndarray) -> list[float]:
    """Share (%) of frames whose true place (the diagonal) is among the top r places, r in RANKS."""
    truth = scores[np.arange(len(scores)), np.arange(len(scores))]
    rank = (scores > truth[:, None]).sum(axis=1)
    return [100 * float(np.mean(rank < r)) for r in RANKS]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("cache", help="route_diagnose's cached counts (.npz with sr, sq)")
    parser.add_argument("--data", required=True)
    parser.add_argument("--query", default="winter")
    parser.add_argument("--calibration-timesteps", type=int)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    vx.set_threads(args.threads)
    ckpt = vx.load_checkpoint(args.checkpoint)
    cfg, ids, reference = ckpt.config, ckpt.reference_place_ids, ckpt.reference_traversals[0]
    cached = np.load(args.cache)
    sr, sq = cached["sr"], cached["sq"]
    data = vx.load_dataset(args.data, [reference, args.query], cfg.preprocess, subset=ids)
    if args.calibration_timesteps:
        net = vx.FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, cfg, torch.device("cpu"))
        longer = cfg.replace(**{"encoder.timesteps": args.calibration_timesteps})
        spikes = calibration_spikes(data.traversal(reference), ids, reference, longer)
        sr = net.counts(spikes).numpy().astype(np.int64).T
        print(f"S^R at T = {args.calibration_timesteps}, queries as cached")
    wprob = Readout.of(sr, cfg, SequenceOptions(ks=(1,))).scores(sq)["wprob"]
    for name, rule, eps in (
        ("product, eps 1e-6 (default)", "product", 1e-6),
        ("product, eps 1e-4", "product", 1e-4),
        ("product, eps 1e-3", "product", 1e-3),
        ("product, eps 1e-2", "product", 1e-2),
        ("sum", "sum", 1e-6),
    ):
        cells = [metrics(aggregate(wprob, k, 1.0, rule, eps=eps), ids) for k in KS]
        print(f"{name:28s} " + "  ".join(f"k={k}: {c}" for k, c in zip(KS, cells, strict=True)))
    cosine = cosine_similarities(data.traversal(reference), data.traversal(args.query))
    for name, scores in (("SNN W+Prob", wprob), ("cosine", cosine)):
        shares = true_rank_shares(scores)
        print(f"true place in the top {'/'.join(map(str, RANKS))}, {name}: " + " / ".join(f"{s:.1f}" for s in shares))
    spikes = sq.sum(axis=1)
    distinct = (sq > 0).sum(axis=1)
    covered = (sr > 0).sum(axis=1)
    print(
        f"output spikes per query {spikes.mean():.0f}, distinct neurons per query (median) {np.median(distinct):.0f}, "
        f"places per neuron that fires at calibration (median) {np.median(covered[covered > 0]):.0f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
