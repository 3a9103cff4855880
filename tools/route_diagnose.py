"""Why a whole-route ensemble loses more to cosine than one module does (issue 34; research log §7).

For a trained ensemble checkpoint: run calibration and the queries (optionally with inference-side changes:
another window T, rate scale or thresholds; training is never touched), then decompose the W+Prob k=1 error
against cosine nearest neighbour on the same images:

* region: the share of queries whose decision lies in the query's own module region (the right module won);
* given region: accuracy among the queries whose decision lies in the right region;
* within region: accuracy when each query's scores are restricted to its own region (the module alone).

    python tools/route_diagnose.py CKPT --data ../shared/data/nordland_64x32_summer_winter --query winter \
        [--timesteps T] [--rate-scale R] [--theta same|offset:X|scale:X] [--cache DIR]

Counts are cached in --cache (one file per checkpoint and variant) so that readouts can be re-run.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

import vprsnn_export as vx
from vprsnn_export.data.encoding import calibration_spikes, query_spikes
from vprsnn_export.readout.baseline import cosine_similarities, diagonal_sums, nearest_neighbour
from vprsnn_export.readout.metrics import is_correct, pr_metrics, predicted_place_ids
from vprsnn_export.readout.scoring import Readout
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.readout.strategies import decide

KS = (1, 5, 10)


def thresholds(theta: np.ndarray, spec: str) -> np.ndarray:
    """The thresholds at inference: the trained ones, all equal to their mean, + X, or x X."""
    if spec == "trained":
        return theta
    if spec == "same":
        return np.full_like(theta, theta.mean())
    kind, _, value = spec.partition(":")
    if kind == "offset":
        return theta + float(value)
    if kind == "scale":
        return theta * float(value)
    if kind == "const":
        return np.full_like(theta, float(value))
    raise SystemExit(f"--theta {spec}: give trained, same, offset:X, scale:X or const:X")


def counts(
    ckpt, cfg, theta, ref, qry, ids, query, cache: Path, key: str, keep_calibration: bool = False
) -> tuple[np.ndarray, np.ndarray, float]:
    """Calibration S^R (neurons, places) and query counts (queries, neurons), cached; seconds spent."""
    path = cache / f"{key}.npz"
    if path.exists():
        z = np.load(path)
        return z["sr"], z["sq"], float(z["seconds"])
    t0 = time.perf_counter()
    net = vx.FloatNetwork.from_arrays(ckpt.weights, theta, cfg, torch.device("cpu"))
    if keep_calibration or (cfg.encoder == ckpt.config.encoder and np.array_equal(theta, ckpt.thresholds)):
        sr = ckpt.calibration  # the checkpoint's own S^R: nothing at calibration changed
    else:
        sr = net.counts(calibration_spikes(ref, ids, ckpt.reference_traversals[0], cfg)).numpy().astype(np.int64).T
    sq = net.counts(query_spikes(qry, ids, query, cfg)).numpy().astype(np.int64)
    seconds = time.perf_counter() - t0
    np.savez(path, sr=sr, sq=sq, seconds=seconds)
    return sr, sq, seconds


def decomposition(scores: np.ndarray, truth: np.ndarray, size: int) -> dict[str, float]:
    """Region share, accuracy given the right region, accuracy within the true region (k=1), in %."""
    pred = np.argmax(scores, axis=1)
    region = pred // size == truth // size
    correct = pred == truth
    n = scores.shape[1]
    starts = (truth // size) * size
    cols = starts[:, None] + np.arange(size)[None, :]
    inside = scores[np.arange(len(truth))[:, None], np.clip(cols, 0, n - 1)]
    within = (np.argmax(inside, axis=1) + starts) == truth
    return {
        "accuracy": 100 * correct.mean(),
        "region": 100 * region.mean(),
        "given_region": 100 * correct[region].mean() if region.any() else 0.0,
        "within_region": 100 * within.mean(),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--data", required=True)
    parser.add_argument("--query", default="winter")
    parser.add_argument("--timesteps", type=int)
    parser.add_argument("--rate-scale", type=float)
    parser.add_argument("--theta", default="trained")
    parser.add_argument("--gamma", type=float)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--cache", default=".scratch/diag")
    parser.add_argument("--json")
    parser.add_argument(
        "--keep-calibration",
        action="store_true",
        help="keep the checkpoint's S^R (its window); change only the queries",
    )
    args = parser.parse_args(argv)
    vx.set_threads(args.threads)
    ckpt = vx.load_checkpoint(args.checkpoint)
    cfg = ckpt.config
    over = {}
    if args.timesteps:
        over["encoder.timesteps"] = args.timesteps
    if args.rate_scale:
        over["encoder.rate_scale"] = args.rate_scale
    if args.gamma is not None:
        over["assignment.gamma"] = args.gamma
    cfg = cfg.replace(**over) if over else cfg
    theta = thresholds(ckpt.thresholds, args.theta)
    ids = ckpt.reference_place_ids
    data = vx.load_dataset(args.data, [ckpt.reference_traversals[0], args.query], cfg.preprocess, subset=ids)
    ref, qry = data.traversal(ckpt.reference_traversals[0]), data.traversal(args.query)
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    tag = hashlib.sha256(Path(args.checkpoint).read_bytes()).hexdigest()[:12]
    key = f"{tag}_T{cfg.encoder.timesteps}_r{cfg.encoder.rate_scale:g}_th{args.theta.replace(':', '')}"
    key += "_keepcal" if args.keep_calibration else ""
    sr, sq, seconds = counts(ckpt, cfg, theta, ref, qry, ids, args.query, cache, key, args.keep_calibration)
    readout = Readout.of(sr, cfg, SequenceOptions(ks=KS))
    size = cfg.train.module_size or len(ids)
    truth = np.arange(len(ids))
    wprob = readout.scores(sq)["wprob"]
    cos = cosine_similarities(ref, qry)
    out = {"variant": key, "seconds": seconds, "spikes_per_query": float(sq.sum(axis=1).mean())}
    out["snn"] = decomposition(wprob, truth, size)
    out["cosine"] = decomposition(cos, truth, size)
    for k in KS:
        dist = readout.options.aggregate(wprob, k)
        pred, conf = decide(dist, "wprob")
        m = pr_metrics(is_correct(predicted_place_ids(pred, ids), ids, 0), conf)
        out["snn"][f"k{k}"] = (100 * m["accuracy"], 100 * m["r_at_100p"])
        pred, conf = nearest_neighbour(diagonal_sums(cos, k))
        m = pr_metrics(is_correct(predicted_place_ids(pred, ids), ids, 0), conf)
        out["cosine"][f"k{k}"] = (100 * m["accuracy"], 100 * m["r_at_100p"])
    print(json.dumps(out, indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    print(f"{seconds:.0f} s of network runs", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
