"""Table V: W+Prob aggregated over k frames, product vs sum rule, on consecutive places.

Beside it, Table IV's conditions at k=5 with four velocity sources (given,
per-window search, tracked over the query stream, smoothed with a fixed lag)
for W+Prob and SAD, from :mod:`.envelope`.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from vprsnn_export.data.truth import EXACT
from vprsnn_export.readout.baseline import cosine_similarities
from vprsnn_export.readout.rules import RULES as AGGREGATION_RULES
from vprsnn_export.readout.scoring import Readout, nearest_neighbour_rows
from vprsnn_export.readout.sequence import SequenceOptions

from . import envelope
from .common import Settings, consecutive_networks, provenance, rows_table, summarise_rows
from .plots import line_plot
from .query import evaluate_query

NAME = "aggregation"
DESCRIPTION = (
    "W+Prob with k in {1, 3, 5, 7, 10, 15}, product vs sum rule, on 100 consecutive places; "
    "at k=5 every operational-envelope condition with the given, per-window searched, tracked and smoothed velocity, "
    "beside SAD on the same windows; cosine nearest neighbour on the network's own input (summed along the diagonal) "
    "at every k as the no-learning template ceiling"
)
#: The ``rule`` column of the cosine baseline's rows: k frames' similarities summed along the diagonal.
COSINE_RULE = "cosine diagonal sum"
KS = (1, 3, 5, 7, 10, 15)
RULES = AGGREGATION_RULES.names()


def run(settings: Settings) -> dict:
    started = time.perf_counter()
    per_seed = []
    velocity_per_seed = []
    for seed, cfg, data, ckpt in consecutive_networks(settings):
        counts = evaluate_query(settings, ckpt, data, cfg)
        rows = []
        for rule in RULES:
            options = SequenceOptions(ks=KS, rule=rule)
            rows += [
                dict(r.to_dict(), rule=rule, seed=seed)
                for r in Readout(ckpt.calibration, cfg.assignment.gamma, options).rows(
                    counts.query_counts, ckpt.reference_place_ids, data.place_ids
                )
                if r.strategy == "wprob"
            ]
        similarities = cosine_similarities(data.traversal(settings.reference), data.traversal(settings.query))
        options = SequenceOptions(ks=KS)
        rows += [
            dict(r.to_dict(), rule=COSINE_RULE, seed=seed)
            for r in nearest_neighbour_rows(
                similarities, "cosine", ckpt.reference_place_ids, data.place_ids, options, EXACT
            )
        ]
        per_seed.append(rows)
        distributions = envelope.network_distributions(settings, cfg, data, ckpt)
        velocity_rows = envelope.envelope_rows(
            distributions, ckpt.reference_place_ids, data.place_ids, np.random.default_rng(seed)
        )
        velocity_per_seed.append([dict(r, seed=seed) for r in velocity_rows])
    return {
        "experiment": NAME,
        "summary": summarise_rows(per_seed, ("rule", "k")),
        "per_seed": per_seed,
        "velocity_sources": {
            "summary": summarise_rows(velocity_per_seed, envelope.KEYS),
            "per_seed": velocity_per_seed,
            **envelope.estimator_settings(),
        },
        "provenance": provenance(settings, started),
    }


def render(results: dict, out_dir: Path, stem: str = NAME) -> str:
    summary = results["summary"]
    series = {}
    for rule in (*RULES, COSINE_RULE):
        rows = [r for r in summary if r["rule"] == rule]
        if not rows:  # a page written before the cosine rows were measured
            continue
        for metric, label in (("r_at_100p", "R@100P"), ("accuracy", "accuracy")):
            name = "cosine NN (no learning)" if rule == COSINE_RULE else f"{rule} rule"
            series[f"{name} {label}"] = (
                [100 * r[metric]["mean"] for r in rows],
                [100 * r[metric]["std"] for r in rows],
            )
    line_plot(
        out_dir / f"{stem}.png",
        list(KS),
        series,
        xlabel="k (frames)",
        ylabel="%",
        title="Sequence aggregation (W+Prob), consecutive places",
    )
    text = rows_table(summary, ("rule", "k")) + f"\n\n![aggregation]({stem}.png)\n"
    velocity = results.get("velocity_sources")
    if velocity:
        text += (
            "\n## Unknown velocity: given, per-window search, tracked and smoothed (Table IV conditions)\n\n"
            + envelope.compact_table(velocity["summary"])
            + "\n\n"
            + envelope.explanation(velocity)
            + "\n### Warm-up: the first queries of the stream\n\n"
            + envelope.warmup_table(velocity["per_seed"], velocity["warmup"])
            + "\n"
        )
    return text
