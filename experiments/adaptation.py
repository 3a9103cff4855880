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
from vprsnn_export.data.truth import EXACT
from vprsnn_export.readout.baseline import cosine_similarities, sad_distances, sad_similarities
from vprsnn_export.readout.metrics import pr_metrics
from vprsnn_export.readout.scoring import Readout, nearest_neighbour_decisions
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.stats import mean_std
from vprsnn_export.trainer.adaptation import adapt_config, place_ranges

from .common import Settings, check_index_scored, provenance, timed_checkpoint, timed_query_counts
from .plots import save_figure

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


#: Per k, one query's decision: (correct, confidence) arrays of the fold's queries.
Decisions = dict[int, tuple[np.ndarray, np.ndarray]]


def snn_decisions(ckpt, counts: np.ndarray, ids: np.ndarray, test: np.ndarray, options: SequenceOptions) -> Decisions:
    """W+Prob at every k (product rule, velocity 1) of the fold's queries against every reference place."""
    scored = Readout.of(ckpt.calibration, ckpt.config, options).score(counts[test], ids, ids[test], EXACT)
    return {k: scored.column("wprob", k).decisions for k in KS}


def template_decisions(
    data: Dataset, settings: Settings, gain, test: np.ndarray, options: SequenceOptions
) -> dict[str, Decisions]:
    """Cosine and SAD on the plain input, cosine on the adapted one, the fold's queries against every place (nearest
    neighbour on k frames summed along the diagonal, margin confidence: ``nearest_neighbour_decisions``)."""
    ids = np.asarray(data.place_ids)

    def nn_decisions(similarities: np.ndarray) -> Decisions:
        return nearest_neighbour_decisions(similarities, ids, ids[test], options, EXACT)

    reference, query = data.traversal(settings.reference), data.traversal(settings.query)[test]
    adapted = cosine_similarities(adapted_inputs(reference, gain), adapted_inputs(query, gain))
    return {
        "cosine, adapted": nn_decisions(adapted),
        "cosine": nn_decisions(cosine_similarities(reference, query)),
        "SAD": nn_decisions(sad_similarities(sad_distances(reference, query))),
    }


def metrics_of(decisions: Decisions) -> dict[str, dict[str, float]]:
    """{k: {accuracy, r_at_100p}} of per-query decisions."""
    out = {}
    for k, (correct, confidence) in decisions.items():
        m = pr_metrics(correct, confidence)
        out[str(k)] = {"accuracy": m["accuracy"], "r_at_100p": m["r_at_100p"]}
    return out


def pooled(per_fold: list[dict[str, Decisions]]) -> list[dict[str, Any]]:
    """Every fold's decisions together: the whole route, each query decided by the network of its own fold."""
    return [
        {
            "matcher": matcher,
            "scores": metrics_of(
                {
                    k: tuple(np.concatenate([fold[matcher][k][i] for fold in per_fold]) for i in (0, 1))  # type: ignore[misc]
                    for k in KS
                }
            ),
        }
        for matcher in MATCHERS
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
    whole: list[dict[str, Any]] = []
    gains: dict[str, list[float]] = {}  # per fold: the pairing and the gain depend on the images only, not the seed
    for seed in settings.seeds:
        per_fold: list[dict[str, Decisions]] = []
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
            gains.setdefault(str(f), [round(g, 4) for g in adaptation.config.encoder.input_gain])
            adapted = timed_checkpoint(settings, data, adaptation.config, f"adaptation-fold{f}")
            counts = timed_query_counts(settings, data, adaptation.config, f"adaptation-fold{f}", adapted.checkpoint)
            decided = {
                "SNN, adapted": snn_decisions(adapted.checkpoint, counts.counts, ids, test, options),
                "SNN": snn_decisions(plain.checkpoint, plain_counts, ids, test, options),
                **template_decisions(data, settings, adaptation.config.encoder.input_gain, test, options),
            }
            per_fold.append(decided)
            rows = [{"matcher": m, "scores": metrics_of(decided[m])} for m in MATCHERS]
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
        whole.append({"seed": seed, "rows": pooled(per_fold)})
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
        "whole_route": whole,
        "image_size": base.preprocess.image_size,
        "gains": gains,
        "summary": summarise(results) + summarise([dict(w, fold="all", places="all") for w in whole]),
        "provenance": provenance(settings, started),
    }


def summarise(results: list[dict]) -> list[dict]:
    """Per fold (or ``"all"``: the folds pooled), matcher and k: accuracy and R@100P, mean ± std over seeds."""
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


def cell(summary: list[dict], fold: int | str, matcher: str, k: int) -> dict:
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
        "**The whole route**: every fold's queries together, each decided by the network (and the gain) of its own "
        "fold, so no query is seen by the learning that decides it:",
        "",
        "| matcher | k=1 | k=5 | k=10 |",
        "|---|---|---|---|",
    ]
    for matcher in MATCHERS:
        cells = [cell(summary, "all", matcher, k) for k in KS]
        lines.append(
            f"| {matcher} | " + " | ".join(f"{pct(c['accuracy'])} / {pct(c['r_at_100p'])}" for c in cells) + " |"
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
        f"Seconds: learning the gain {min(learn):.2f}-{max(learn):.2f} s per fold; training an adapted ensemble "
        f"{min(seconds):.0f}-{max(seconds):.0f} s, the plain one "
        f"{min(r['plain_train_seconds'] for r in results['results']):.0f}-"
        f"{max(r['plain_train_seconds'] for r in results['results']):.0f} s (cached networks keep the seconds of the "
        "run that trained them).",
    ]
    if results.get("gains"):
        gain_plot(out_dir / f"{stem}.png", results["gains"], results["image_size"])
        lines += [
            "",
            f"![the learnt gain of each fold]({stem}.png)",
            "",
            "The gain of each fold as an image: each row of the resized image holds its ON inputs, then its OFF inputs.",
        ]
    return "\n".join(lines) + "\n"


def gain_plot(path: Path, gains: dict[str, list[float]], size: int) -> Path:
    """One panel per fold: g_i laid out as the input image (ON | OFF side by side in each row)."""
    import matplotlib.pyplot as plt

    maps = {fold: np.asarray(g).reshape(size, -1) for fold, g in gains.items()}
    top = max(float(m.max()) for m in maps.values())
    fig, axes = plt.subplots(1, len(maps), figsize=(3.2 * len(maps), 2.2), squeeze=False)
    for ax, (fold, image) in zip(axes[0], maps.items(), strict=True):
        shown = ax.imshow(image, cmap="viridis", vmin=0, vmax=top)
        ax.set_title(f"fold {fold}: gain, ON | OFF", fontsize=9)
        ax.axvline(image.shape[1] / 2 - 0.5, color="white", linewidth=0.8)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(shown, ax=axes[0].tolist(), shrink=0.8, label="g_i")
    return save_figure(fig, path)
