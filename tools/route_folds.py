"""Adaptation from an unlabelled second traversal, judged on folds (issue 34; docs/research/route-recognition.md §8).

No learning of the network: cosine nearest neighbour on the network's own input (the preprocessed images, DoG
ON/OFF by default) is the judge. For each fold the statistics are learnt from the reference traversal and the
query traversal's frames of the *other* folds only, paired without labels by k-frame sequence matching
(cosine summed along the diagonal, references = every place), and the fold's own query frames are scored against
every reference place. Per fold and k: SAD and cosine on the plain input, cosine on each adapted input, accuracy
(exact match) and R@100P in %.

    python tools/route_folds.py --data ../shared/data/nordland_64x32_summer_winter --reference summer \
        --query winter --folds 4
    python tools/route_folds.py --data ../shared/data/lens_example_davis128 --reference example-reference \
        --query example-query --folds 2

Candidates (x: one flattened input image; pairs (a_p, b_p): reference image and matched query frame):

* ``gain``: per-input gain g_i = sqrt(Var_between,i / (Var_within,i + mean_j Var_within,j)), x -> g * x,
  with the pair means m_p = (a_p + b_p) / 2, Var_between,i = Var_p(m_pi), Var_within,i = mean_p (a_pi - b_pi)^2 / 4.
* ``whiten-L``: x -> (Sigma_within + L mean eig(Sigma_within) I)^(-1/2) x with Sigma_within = mean_p d_p d_p^T,
  d_p = (a_p - b_p) / sqrt(2).
* ``centre``: each traversal minus its own mean (the reference over every place, the query traversal over the
  learning folds' frames).
* ``gain+centre``: both.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable

import numpy as np

import vprsnn_export as vx
from vprsnn_export.readout.baseline import (
    cosine_similarities,
    diagonal_sums,
    nearest_neighbour,
    sad_distances,
    sad_similarities,
)
from vprsnn_export.readout.metrics import is_correct, pr_metrics, predicted_place_ids
from vprsnn_export.trainer.adaptation import input_gain, sequence_pairs

KS = (1, 5, 10)


def score(
    similarities: np.ndarray, truth: np.ndarray, tolerance: int = 0, ks: tuple[int, ...] = KS
) -> dict[int, tuple[float, float]]:
    """Accuracy and R@100P (%) of nearest neighbour on k-frame diagonal sums, per k (``tolerance``: places of slack,
    0 = exact match)."""
    out = {}
    shift = similarities.min()
    s = similarities - shift if shift < 0 else similarities  # diagonal_sums needs non-negative similarities
    for k in ks:
        pred, conf = nearest_neighbour(diagonal_sums(s, k))
        correct = is_correct(predicted_place_ids(pred, np.arange(s.shape[1])), truth, tolerance)
        m = pr_metrics(correct, conf)
        out[k] = (100 * m["accuracy"], 100 * m["r_at_100p"])
    return out


def whitener(a: np.ndarray, b: np.ndarray, lam: float) -> np.ndarray:
    """(Sigma_within + lam mean eig I)^(-1/2), Sigma_within = mean_p d_p d_p^T, d_p = (a_p - b_p) / sqrt(2)."""
    d = (a - b) / np.sqrt(2)
    sigma = d.T @ d / len(d)
    eig, vec = np.linalg.eigh(sigma)
    eig = np.clip(eig, 0, None)
    return (vec / np.sqrt(eig + lam * eig.mean())) @ vec.T


Adapter = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def adapters(lams: tuple[float, ...]) -> dict[str, Adapter]:
    """Each candidate: (reference, queries, pair references a, pair frames b) -> adapted (reference, queries)."""

    def by_gain(ref, qry, a, b):
        g = input_gain(a, b)
        return ref * g, qry * g

    def by_centre(ref, qry, a, b):
        return ref - ref.mean(axis=0), qry - b.mean(axis=0)

    def by_both(ref, qry, a, b):
        g = input_gain(a, b)
        return (ref - ref.mean(axis=0)) * g, (qry - b.mean(axis=0)) * g

    out: dict[str, Adapter] = {"gain": by_gain, "centre": by_centre, "gain+centre": by_both}
    for lam in lams:

        def by_whitening(ref, qry, a, b, lam=lam):
            w = whitener(a, b, lam)
            return ref @ w, qry @ w

        out[f"whiten-{lam:g}"] = by_whitening
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", required=True)
    parser.add_argument("--reference", required=True)
    parser.add_argument("--query", required=True)
    parser.add_argument("--folds", type=int, default=4, help="consecutive folds of the route (default 4)")
    parser.add_argument("--pair-k", type=int, default=10, help="frames of the sequence matching that pairs frames")
    parser.add_argument("--true-pairs", action="store_true", help="pair by ground truth instead (an upper bound)")
    parser.add_argument("--lambdas", default="0.1,1", help="whitening regularisers L (comma-separated)")
    parser.add_argument("--match-window", type=int, default=0, help="places of slack in the ground truth (0: exact)")
    parser.add_argument("--json", help="also write the table as JSON to this file")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    cfg = vx.Config()
    data = vx.load_dataset(args.data, [args.reference, args.query], cfg.preprocess)
    ref = data.traversal(args.reference).astype(np.float64)
    qry = data.traversal(args.query).astype(np.float64)
    n = len(ref)
    folds = np.array_split(np.arange(n), args.folds)
    lams = tuple(float(v) for v in args.lambdas.split(","))
    cands = adapters(lams)
    rows = []
    for f, test in enumerate(folds):
        learn = [fold for g, fold in enumerate(folds) if g != f]
        frames = qry[np.concatenate(learn)]
        if args.true_pairs:
            pairs = np.concatenate(learn)
        else:
            pairs = sequence_pairs(ref, frames, np.concatenate(learn), args.pair_k)
        pair_ok = float(np.mean(pairs == np.concatenate(learn)))
        a, b = ref[pairs], frames
        results = {
            "SAD": score(sad_similarities(sad_distances(ref, qry[test])), test, args.match_window),
            "cosine": score(cosine_similarities(ref, qry[test]), test, args.match_window),
        }
        for name, adapt in cands.items():
            r2, q2 = adapt(ref, qry[test], a, b)
            results[f"cosine, {name}"] = score(cosine_similarities(r2, q2), test, args.match_window)
        rows.append(
            {
                "fold": f,
                "places": f"{test[0]}-{test[-1]}",
                "pairs_correct": pair_ok,
                "results": {m: {str(k): v for k, v in r.items()} for m, r in results.items()},
            }
        )
        print(f"fold {f} done ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    print(table(rows))
    print(f"\n{time.perf_counter() - t0:.1f} s", file=sys.stderr)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(rows, fh, indent=1)
    return 0


def table(rows: list[dict]) -> str:
    """Markdown: one row per (fold, matcher), accuracy / R@100P per k, and whether each adapted matcher lifts
    plain cosine on every fold (accuracy above at k = 1 and not below at k = 5, 10)."""
    lines = [
        "| fold (places; pairs right) | matcher | k=1 | k=5 | k=10 |",
        "|---|---|---|---|---|",
    ]
    for row in rows:
        for name, res in row["results"].items():
            cells = " | ".join(f"{res[str(k)][0]:.1f} / {res[str(k)][1]:.1f}" for k in KS)
            label = f"{row['fold']} ({row['places']}; {100 * row['pairs_correct']:.0f} %)"
            lines.append(f"| {label} | {name} | {cells} |")
    names = [m for m in rows[0]["results"] if m.startswith("cosine, ")]
    lines.append("")
    lines.append("| adapted matcher | mean change vs cosine k=1 / 5 / 10 (points) | lifts cosine on every fold |")
    lines.append("|---|---|---|")
    for name in names:
        deltas = np.array(
            [[r["results"][name][str(k)][0] - r["results"]["cosine"][str(k)][0] for k in KS] for r in rows]
        )
        holds = bool(np.all(deltas[:, 0] > 0) and np.all(deltas[:, 1:] >= 0))
        mean = " / ".join(f"{d:+.1f}" for d in deltas.mean(axis=0))
        lines.append(f"| {name} | {mean} | {'yes' if holds else 'no'} |")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
