"""Adaptation from the query traversal's unlabelled frames, cross-fitted on folds (issue 34; research log §8, §15).

The route's places are cut into consecutive folds (quarters from 400 places on, else halves). For each fold, the
per-input gain (trainer/adaptation.py) is learnt from the reference traversal and the query traversal's frames of
the *other* folds only, paired without labels by sequence matching; an ensemble is trained on every reference place
with that gain (``train --adapt-from QUERY --adapt gain --adapt-places OTHER_FOLDS``), and the fold's own query
frames are scored against every reference place. No query frame that is scored is seen by any learning: not by STDP,
calibration or the gain. Per fold and k, accuracy and R@100P (exact match) of W+Prob for the adapted network and the
plain one (trained once per seed, no adaptation), and of cosine and SAD nearest neighbour on the plain input and
cosine on the adapted input; the seconds of learning the gain and of training.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from vprsnn_export.config import Config, preset
from vprsnn_export.data.dataset import Dataset, load_dataset
from vprsnn_export.data.encoding import adapted_inputs
from vprsnn_export.readout.baseline import cosine_similarities, sad_distances, sad_similarities
from vprsnn_export.readout.scoring import Readout, nearest_neighbour_rows
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.stats import mean_std
from vprsnn_export.trainer.adaptation import adapt_config, place_ranges

from .common import Settings, check_index_scored, provenance, timed_checkpoint, timed_query_counts

NAME = "adaptation"
DESCRIPTION = (
    "adaptation from the query traversal's unlabelled frames (the per-input gain), cross-fitted on folds of the "
    "route: the adapted and the plain SNN against cosine and SAD on the plain input and cosine on the adapted input"
)
KS = (1, 5, 10)
MODULE_SIZE, QUICK_MODULE_SIZE = 100, 8
MECHANISM = "gain"
MATCHERS = ("SNN, adapted", "SNN", "cosine, adapted", "cosine", "SAD")


def stem(settings: Settings) -> str:
    """The page's name: ``adaptation`` on the default data (the dev route), ``adaptation_<folder>`` on another."""
    if settings.data == Settings().data or settings.quick:
        return NAME
    path = Path(settings.data)
    folder = path.parent.name if path.suffix == ".csv" else path.name
    return f"{NAME}_" + "".join(c if c.isalnum() else "_" for c in folder)


def fold_count(n_places: int) -> int:
    """Quarters of a route of 400 places or more (the dev route), halves of a shorter one (the LENS example)."""
    return 4 if n_places >= 400 else 2


def route_config(settings: Settings, seed: int) -> Config:
    size = QUICK_MODULE_SIZE if settings.quick else MODULE_SIZE
    return preset("dog").replace(**{**settings.overrides, "seed": seed, "train.module_size": size})


def rows_of(rows: list, matcher: str) -> dict[str, Any]:
    """{k: {accuracy, r_at_100p}} of the W+Prob (SNN) or nearest-neighbour rows."""
    out = {}
    for row in rows:
        r = row.to_dict()
        if r["strategy"] in ("wprob", "cosine", "sad") and r["k"] in KS:
            out[str(r["k"])] = {"accuracy": r["accuracy"], "r_at_100p": r["r_at_100p"]}
    return {"matcher": matcher, "scores": out}


def snn_rows(ckpt, counts: np.ndarray, ids: np.ndarray, test: np.ndarray, options: SequenceOptions) -> list:
    return Readout.of(ckpt.calibration, ckpt.config, options).scored(counts[test], ids, ids[test])[0]


def template_rows(data: Dataset, settings: Settings, gain, test: np.ndarray, options: SequenceOptions) -> list[dict]:
    """Cosine and SAD on the plain input, cosine on the adapted one, the fold's queries against every place."""
    ids = data.place_ids
    reference, query = data.traversal(settings.reference), data.traversal(settings.query)[test]
    adapted = cosine_similarities(adapted_inputs(reference, gain), adapted_inputs(query, gain))
    return [
        rows_of(nearest_neighbour_rows(adapted, "cosine", ids, ids[test], options), "cosine, adapted"),
        rows_of(
            nearest_neighbour_rows(cosine_similarities(reference, query), "cosine", ids, ids[test], options), "cosine"
        ),
        rows_of(
            nearest_neighbour_rows(sad_similarities(sad_distances(reference, query)), "sad", ids, ids[test], options),
            "SAD",
        ),
    ]


def run(settings: Settings) -> dict:
    started = time.perf_counter()
    options = SequenceOptions(ks=KS, velocity=1.0)
    base = route_config(settings, settings.seeds[0])
    data = load_dataset(settings.data, [settings.reference, settings.query], base.preprocess, progress=False)
    check_index_scored(data, settings.reference, settings.query)
    ids = np.asarray(data.place_ids)
    folds = np.array_split(np.arange(len(ids)), fold_count(len(ids)))
    results: list[dict[str, Any]] = []
    for seed in settings.seeds:
        cfg = route_config(settings, seed)
        plain = timed_checkpoint(settings, data, cfg, "adaptation-plain")
        plain_counts = timed_query_counts(settings, data, cfg, "adaptation-plain", plain.checkpoint).counts
        for f, test in enumerate(folds):
            if settings.progress:
                print(f"adaptation: seed {seed}, fold {f + 1} of {len(folds)}", flush=True)
            learn = np.concatenate([fold for g, fold in enumerate(folds) if g != f])
            clock = time.perf_counter()
            adaptation = adapt_config(data, [settings.reference], settings.query, cfg, places=ids[learn])
            learn_seconds = time.perf_counter() - clock
            adapted = timed_checkpoint(settings, data, adaptation.config, f"adaptation-fold{f}")
            counts = timed_query_counts(settings, data, adaptation.config, f"adaptation-fold{f}", adapted.checkpoint)
            rows = [
                rows_of(snn_rows(adapted.checkpoint, counts.counts, ids, test, options), "SNN, adapted"),
                rows_of(snn_rows(plain.checkpoint, plain_counts, ids, test, options), "SNN"),
                *template_rows(data, settings, adaptation.config.encoder.input_gain, test, options),
            ]
            results.append(
                {
                    "seed": seed,
                    "fold": f,
                    "places": place_ranges(ids[test]),
                    "learnt_from": adaptation.summary,
                    "pairs_at_own_place": adaptation.record["pairs_at_own_place"],
                    "learn_seconds": round(learn_seconds, 2),
                    "train_seconds": round(adapted.train_seconds, 1),
                    "plain_train_seconds": round(plain.train_seconds, 1),
                    "rows": rows,
                }
            )
    return {
        "experiment": NAME,
        "data": settings.data,
        "reference": settings.reference,
        "query": settings.query,
        "n_places": len(ids),
        "folds": len(folds),
        "mechanism": MECHANISM,
        "ks": list(KS),
        "results": results,
        "summary": summarise(results),
        "provenance": provenance(settings, started),
    }


def summarise(results: list[dict]) -> list[dict]:
    """Per fold, matcher and k: accuracy and R@100P, mean ± std over seeds; and whether the adapted SNN is at or
    above cosine on the plain input (the issue's rule) and above the plain SNN."""
    out = []
    for fold in sorted({r["fold"] for r in results}):
        mine = [r for r in results if r["fold"] == fold]
        for matcher in MATCHERS:
            for k in KS:
                cells = [next(x for x in r["rows"] if x["matcher"] == matcher)["scores"][str(k)] for r in mine]
                out.append(
                    {
                        "fold": fold,
                        "places": mine[0]["places"],
                        "matcher": matcher,
                        "k": k,
                        "accuracy": mean_std(c["accuracy"] for c in cells).to_dict(),
                        "r_at_100p": mean_std(c["r_at_100p"] for c in cells).to_dict(),
                    }
                )
    return out


def cell(summary: list[dict], fold: int, matcher: str, k: int) -> dict:
    return next(s for s in summary if s["fold"] == fold and s["matcher"] == matcher and s["k"] == k)


def render(results: dict, out_dir: Path, stem: str = NAME) -> str:
    summary = results["summary"]
    seeds = sorted({r["seed"] for r in results["results"]})
    folds = range(results["folds"])

    def pct(value: dict) -> str:
        return f"{100 * value['mean']:.1f}" + (f" ± {100 * value['std']:.1f}" if value["n"] > 1 else "")

    lines = [
        f"Data `{results['data']}`: reference '{results['reference']}', query '{results['query']}', "
        f"{results['n_places']} places in {results['folds']} folds; seeds {', '.join(map(str, seeds))}. For each "
        "fold, the per-input gain is learnt from the reference and the query frames of the other folds, paired "
        "without labels (k = 10 sequence matching), the adapted ensemble is trained on every reference place, "
        "and the fold's queries are scored against every place (exact match, velocity 1). Accuracy / R@100P in % "
        "(mean ± std over seeds).",
        "",
        "| fold (places) | matcher | k=1 | k=5 | k=10 |",
        "|---|---|---|---|---|",
    ]
    for f in folds:
        places = cell(summary, f, "SNN", 1)["places"]
        for matcher in MATCHERS:
            cells = [cell(summary, f, matcher, k) for k in KS]
            lines.append(
                f"| {f} ({places}) | {matcher} | "
                + " | ".join(f"{pct(c['accuracy'])} / {pct(c['r_at_100p'])}" for c in cells)
                + " |"
            )
    lines += [
        "",
        "Change of accuracy in points, mean over seeds (adapted SNN minus the matcher), per fold, k = 1 / 5 / 10:",
        "",
    ]
    lines += [
        "| fold | vs the plain SNN | vs cosine on the plain input | at or above cosine at every k |",
        "|---|---|---|---|",
    ]
    every = True
    for f in folds:

        def diff(other: str, f: int = f) -> list[float]:
            return [
                100
                * (
                    cell(summary, f, "SNN, adapted", k)["accuracy"]["mean"]
                    - cell(summary, f, other, k)["accuracy"]["mean"]
                )
                for k in KS
            ]

        plain, cosine = diff("SNN"), diff("cosine")
        holds = all(d >= 0 for d in cosine)
        every &= holds
        lines.append(
            f"| {f} | {' / '.join(f'{d:+.1f}' for d in plain)} | {' / '.join(f'{d:+.1f}' for d in cosine)} | "
            f"{'yes' if holds else 'no'} |"
        )
    seconds = [r["train_seconds"] for r in results["results"]]
    learn = [r["learn_seconds"] for r in results["results"]]
    lines += [
        "",
        f"The adapted SNN is at or above cosine on the plain input at every k on every fold: **{'yes' if every else 'no'}**.",
        "",
        f"Seconds: learning the gain {min(learn):.1f}-{max(learn):.1f} s per fold; training an adapted ensemble "
        f"{min(seconds):.0f}-{max(seconds):.0f} s, the plain one "
        f"{min(r['plain_train_seconds'] for r in results['results']):.0f}-"
        f"{max(r['plain_train_seconds'] for r in results['results']):.0f} s (cached networks keep the seconds of the "
        "run that trained them).",
    ]
    return "\n".join(lines) + "\n"
