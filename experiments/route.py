"""The whole shared route: ensembles of modules at k = 1, 5, 10 against the no-learning baselines on the same places.

Every network is an ensemble of ``train.module_size``-place modules in the default configuration
(DoG ON/OFF, 60 epochs), trained on the summer traversal of the route's places and read out over
the whole route (S^R of every module's neurons for every place) on the winter traversal: Standard,
Weighted and W+Prob at k = 1 and W+Prob aggregated at k = 5, 10 (product rule, the given velocity of
one place per frame, and the velocity estimated from the query stream). Each network is read out
without the region regularisation, with each of its two parts and with both (the default:
region-specific assignment, lambda = ``assignment.outside_weight`` = 0, and hyperactive neurons
silenced, rho = ``assignment.hyperactive_share`` = 0.5; docs/readout.md section 6). The
ensemble is read with its configured WTA scope (``network.wta_scope`` = ensemble: one winner per step
over all modules, the default) and, for comparison, with one WTA per module (the earlier default:
the same trained weights, S^R recounted). The baselines on the same places: cosine nearest neighbour
and SAD nearest neighbour on the DoG images the network sees (margin confidence, scores summed along
the diagonal; the template ceiling of issue 20), and SAD on the patch-normalised images read out like
W+Prob (the earlier bar).
"""

from __future__ import annotations

import time
import tracemalloc
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from vprsnn_export.config import Config, preset
from vprsnn_export.data.dataset import Dataset
from vprsnn_export.data.truth import EXACT
from vprsnn_export.readout.baseline import cosine_similarities, sad_distances, sad_distribution, sad_similarities
from vprsnn_export.readout.regions import hyperactive_neurons, module_layout
from vprsnn_export.readout.scoring import (
    Readout,
    baseline_rows,
    decision_metrics,
    metric_row,
    nearest_neighbour_rows,
)
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.readout.strategies import STRATEGIES
from vprsnn_export.stats import mean_std

from .common import (
    Settings,
    TimedCheckpoint,
    load,
    pct,
    provenance,
    rescoped_checkpoint,
    summarise_rows,
    timed_checkpoint,
    timed_query_counts,
)
from .plots import route_plot

NAME = "route"
DESCRIPTION = (
    "whole shared route: ensembles of 50/100/200-place modules, W+Prob at k = 1, 5, 10 vs SAD on the same "
    "places, with and without the region regularisation; training and inference time, memory"
)
FULL_PLACES = "0:2400"
QUICK_PLACES = "0:24"
FULL_SIZES = (100, 50, 200)  # 100 first: the goals are measured on it
QUICK_SIZES = (8, 12)
OTHER_SIZE_SEEDS = 1  # module sizes after the first (the main one) are trained for the first seed only
ROUTE_PRESET = "dog"  # the default configuration
KS = (1, 5, 10)
VELOCITY = 1.0  # given velocity, places per frame (the route is driven at one place per frame)
VELOCITY_GRID = tuple(round(0.5 + 0.1 * i, 1) for i in range(11))  # 0.5 .. 1.5 places per frame, for the estimate
#: The readouts of every network: (name, lambda = outside_weight, rho = hyperactive_share, WTA scope).
READOUTS = (
    ("none", 1.0, 1.0, "ensemble"),
    ("silence", 1.0, 0.5, "ensemble"),
    ("region", 0.0, 1.0, "ensemble"),
    ("region+silence", 0.0, 0.5, "ensemble"),
    ("module WTA, region+silence", 0.0, 0.5, "module"),  # the default before issue 20
)
DEFAULT_READOUT = "region+silence"  # the config's defaults (AssignmentConfig, network.wta_scope)
PREVIOUS_READOUT = "module WTA, region+silence"
#: Issue 20's goals per k: (W+Prob accuracy, W+Prob R@100P), 3 seeds, exact match.
GOALS = {1: (0.45, None), 5: (0.88, 0.80), 10: (0.92, 0.92)}


def route_settings(settings: Settings) -> Settings:
    """The route's selection: the manifest's first 2400 places (quick: 24 synthetic places)."""
    return replace(
        settings, consecutive=QUICK_PLACES if settings.quick else FULL_PLACES, subset=None, preset=ROUTE_PRESET
    )


def route_config(settings: Settings, seed: int, module_size: int) -> Config:
    """The default configuration (DoG, 60 epochs) with ``train.module_size`` set, plus the settings' overrides."""
    return preset(ROUTE_PRESET).replace(**{**settings.overrides, "seed": seed, "train.module_size": module_size})


def route_data(settings: Settings, cfg: Config) -> Dataset:
    return load(settings, "consecutive", cfg, places=route_settings(settings).consecutive)


def route_network(settings: Settings, seed: int, module_size: int) -> tuple[Config, Dataset, TimedCheckpoint]:
    """The trained (or cached) ensemble of ``module_size``-place modules for one seed."""
    cfg = route_config(settings, seed, module_size)
    data = route_data(settings, cfg)
    return cfg, data, timed_checkpoint(settings, data, cfg, f"route{module_size}")


def options(estimate: bool = False) -> dict[str, Any]:
    """SequenceOptions keywords: the given velocity, or the smoothed estimate over :data:`VELOCITY_GRID`."""
    if estimate:
        return {"velocity_candidates": VELOCITY_GRID, "velocity_estimate": "smooth"}
    return {"velocity": VELOCITY}


def baselines(settings: Settings) -> dict[str, list[dict]]:
    """The no-learning rows at every k (given velocity): SAD read out like W+Prob on the patch-normalised
    ("intensity") and DoG ("dog_on_off") images, and cosine and SAD nearest neighbour on the DoG images
    ("cosine", "sad_nn"). Each traversal is loaded and each distance matrix computed once."""
    out: dict[str, list[dict]] = {}
    for channels in ("intensity", "dog_on_off"):
        cfg = preset("paper" if channels == "intensity" else ROUTE_PRESET).replace(**settings.overrides)
        data = route_data(settings, cfg)
        reference, query = data.traversal(settings.reference), data.traversal(settings.query)
        ids = data.place_ids
        opts = SequenceOptions(ks=KS, **options())
        distances = sad_distances(reference, query)
        distribution = sad_distribution(distances)
        out[channels] = [r.to_dict() for r in baseline_rows(distribution, ids, ids, opts, EXACT)]
        if channels == "dog_on_off":
            cosine = nearest_neighbour_rows(cosine_similarities(reference, query), "cosine", ids, ids, opts, EXACT)
            out["cosine"] = [r.to_dict() for r in cosine]
            sad = nearest_neighbour_rows(sad_similarities(distances), "sad", ids, ids, opts, EXACT)
            out["sad_nn"] = [r.to_dict() for r in sad]
    return out


def readout(
    ckpt, counts: np.ndarray, data: Dataset, cfg: Config, name: str, lam: float, rho: float, estimate: bool
) -> tuple[list[dict], Any, float, float]:
    """Rows of one readout (velocity given; with ``estimate`` also W+Prob at k > 1 with the velocity
    estimated from the query stream, strategy "wprob-est"), the layout and W+Prob, the seconds and the
    peak numpy memory (MiB) the velocity-given part took."""
    layout = module_layout(cfg, len(data.place_ids), rho, lam)
    ids = data.place_ids
    tracemalloc.start()
    started = time.perf_counter()
    scored = Readout(ckpt.calibration, cfg.assignment.gamma, SequenceOptions(ks=KS, **options()), layout).score(
        counts, ids, ids, EXACT
    )
    rows, scores = scored.rows, scored.scores
    seconds = time.perf_counter() - started
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    if estimate:
        searched = SequenceOptions(ks=KS, **options(True))
        for k in KS[1:]:
            dist = searched.aggregate(scores["wprob"], k)
            rows.append(metric_row("wprob-est", k, decision_metrics(dist, "wprob", ids, ids, EXACT)))
    return [dict(r.to_dict(), readout=name) for r in rows], (layout, scored), seconds, peak


def evaluate_network(settings: Settings, module_size: int, seed: int) -> dict[str, Any]:
    """Train (or reuse) one ensemble, run it on the query traversal, read it out at every rho."""
    cfg, data, timed = route_network(settings, seed, module_size)
    key = f"route{module_size}"
    query = timed_query_counts(settings, data, cfg, key, timed.checkpoint)
    counts = query.counts
    scoped = {cfg.network.wta_scope: (timed.checkpoint, counts)}
    rows: list[dict] = []
    readouts = []
    for name, lam, rho, scope in READOUTS:
        if scope not in scoped:
            scope_cfg, scope_ckpt = rescoped_checkpoint(settings, data, timed.checkpoint, scope, key)
            scoped[scope] = (scope_ckpt, timed_query_counts(settings, data, scope_cfg, key, scope_ckpt).counts)
        ckpt, scope_counts = scoped[scope]
        some, (layout, scored), seconds, peak = readout(
            ckpt, scope_counts, data, ckpt.config, name, lam, rho, name == DEFAULT_READOUT
        )
        rows += some
        readouts.append(
            {
                "readout": name,
                "outside_weight": lam,
                "hyperactive_share": rho,
                "wta_scope": scope,
                "silenced": int(hyperactive_neurons(ckpt.calibration, layout).sum()),
                "readout_seconds": round(seconds, 2),
                "readout_peak_mib": round(peak, 1),
                "modules": [m.to_dict() for m in scored.regions(layout.regions)],
            }
        )
    ckpt = timed.checkpoint
    model_bytes = ckpt.weights.astype(np.float32).nbytes + ckpt.thresholds.astype(np.float32).nbytes
    return {
        "module_size": module_size,
        "seed": seed,
        "modules": len(module_layout(cfg, len(data.place_ids)).regions),
        "neurons": int(ckpt.weights.shape[1]),
        "train_seconds": round(timed.train_seconds, 1),
        "trained_on": timed.trained_on,
        "cached": timed.cached,
        "query_seconds": round(query.seconds, 2),
        "query_ms_per_image": round(1000 * query.seconds / len(data.place_ids), 2),
        "weights_mib": round(model_bytes / 2**20, 2),
        "calibration_mib": round(ckpt.calibration.astype(np.int64).nbytes / 2**20, 2),
        "mean_spikes_per_query": float(counts.sum(axis=1).mean()),
        "readouts": readouts,
        "rows": rows,
    }


def run(settings: Settings) -> dict:
    started = time.perf_counter()
    settings = route_settings(settings)
    sizes = settings.module_sizes or (QUICK_SIZES if settings.quick else FULL_SIZES)
    main = sizes[0]
    networks = []
    for size in sizes:
        seeds = settings.seeds if size == main else settings.seeds[:OTHER_SIZE_SEEDS]
        for seed in seeds:
            if settings.progress:
                print(f"route: module size {size}, seed {seed}", flush=True)
            networks.append(evaluate_network(settings, size, seed))
    summary = []
    for size in sizes:
        mine = [n for n in networks if n["module_size"] == size]
        for row in summarise_rows([n["rows"] for n in mine], keys=("readout", "strategy", "k")):
            summary.append({"module_size": size, **row})
    no_learning = baselines(settings)
    return {
        "experiment": NAME,
        "places": settings.consecutive,
        "n_places": networks[0]["rows"][0]["n_queries"],
        "main_module_size": main,
        "ks": list(KS),
        "velocity": VELOCITY,
        "velocity_grid": list(VELOCITY_GRID),
        "readouts": [
            {"readout": n, "outside_weight": lam, "hyperactive_share": rho, "wta_scope": scope}
            for n, lam, rho, scope in READOUTS
        ],
        "default_readout": DEFAULT_READOUT,
        "previous_readout": PREVIOUS_READOUT,
        "goals": {str(k): {"accuracy": a, "r_at_100p": r} for k, (a, r) in GOALS.items()},
        "networks": networks,
        "summary": summary,
        "baselines": no_learning,
        "cost": cost_summary(networks, sizes),
        "provenance": provenance(settings, started),
    }


def cost_summary(networks: list[dict], sizes) -> list[dict]:
    """Per module size: mean ± std over seeds of the training, query and readout seconds."""
    out = []
    for size in sizes:
        mine = [n for n in networks if n["module_size"] == size]
        out.append(
            {
                "module_size": size,
                "modules": mine[0]["modules"],
                "neurons": mine[0]["neurons"],
                "seeds": [n["seed"] for n in mine],
                "train_seconds": mean_std(n["train_seconds"] for n in mine).to_dict(),
                "query_seconds": mean_std(n["query_seconds"] for n in mine).to_dict(),
                "query_ms_per_image": mean_std(n["query_ms_per_image"] for n in mine).to_dict(),
                "readout_seconds": mean_std(
                    r["readout_seconds"] for n in mine for r in n["readouts"] if r["readout"] == DEFAULT_READOUT
                ).to_dict(),
                "readout_peak_mib": max(r["readout_peak_mib"] for n in mine for r in n["readouts"]),
                "weights_mib": mine[0]["weights_mib"],
                "calibration_mib": mine[0]["calibration_mib"],
                "mean_spikes_per_query": mean_std(n["mean_spikes_per_query"] for n in mine).to_dict(),
            }
        )
    return out


def _label(strategy: str, k: int) -> str:
    names = {s.name: s.title for s in STRATEGIES.values()} | {"wprob-est": "W+Prob, v estimated"}
    return f"{names.get(strategy, strategy)} k={k}"


def _find(summary: list[dict], size: int, readout: str, strategy: str, k: int) -> dict | None:
    for row in summary:
        if (row["module_size"], row["readout"], row["strategy"], row["k"]) == (size, readout, strategy, k):
            return row
    return None


def render(results: dict, out_dir: Path, stem: str = NAME) -> str:
    summary = results["summary"]
    main = results["main_module_size"]
    default = results["default_readout"]
    names = [r["readout"] for r in results["readouts"]]
    sizes = [c["module_size"] for c in results["cost"]]
    sad = {r["k"]: r for r in results["baselines"]["intensity"]}
    sad_dog = {r["k"]: r for r in results["baselines"]["dog_on_off"]}
    main_seeds = next(c["seeds"] for c in results["cost"] if c["module_size"] == main)
    lines = [
        f"Whole route: places {results['places']} ({results['n_places']} places), reference summer, query winter, "
        f"exact match; velocity {results['velocity']:g} place per frame unless estimated (smooth, grid "
        f"{results['velocity_grid'][0]:g}..{results['velocity_grid'][-1]:g}). Percent, mean ± std over seeds. "
        "Readouts (docs/readout.md section 6): "
        + "; ".join(
            f"{r['readout']}: lambda = {r['outside_weight']:g}, rho = {r['hyperactive_share']:g}"
            for r in results["readouts"]
        )
        + f" ({default} is the config's default).",
        "",
        "## Against storing the reference images (issue 20)",
        "",
        f"W+Prob of the {main}-place modules (seeds {', '.join(map(str, main_seeds))}), accuracy / R@100P in %, "
        f"against the no-learning baselines on the same places: cosine and SAD nearest neighbour on the DoG images "
        "the network sees (margin confidence, scores summed along the diagonal) and SAD on the patch-normalised "
        "images read out like W+Prob (the earlier bar). The goals are issue 20's.",
        "",
        f"| k | SNN, one WTA over the ensemble ({default}, the default) | SNN, one WTA per module "
        "(the earlier default) | cosine NN, DoG | SAD NN, DoG | SAD, patch-normalised | goal | goal met |",
        "|---:|---|---|---:|---:|---:|---|---|",
    ]
    baselines = results["baselines"]

    def nn(name: str, k: int) -> str:
        row = next((r for r in baselines.get(name, []) if r["k"] == k), None)
        return "-" if row is None else f"{100 * row['accuracy']:.1f} / {100 * row['r_at_100p']:.1f}"

    for k in results["ks"]:
        on = _find(summary, main, default, "wprob", k)
        before = _find(summary, main, results.get("previous_readout", ""), "wprob", k)
        if on is None:
            continue
        goal = results["goals"].get(str(k), {})
        met = on["accuracy"]["mean"] >= goal.get("accuracy", 0) and (
            goal.get("r_at_100p") is None or on["r_at_100p"]["mean"] >= goal["r_at_100p"]
        )
        goal_text = f"{100 * goal['accuracy']:.0f}" + (
            f" / {100 * goal['r_at_100p']:.0f}" if goal.get("r_at_100p") is not None else ""
        )
        was = "-" if before is None else f"{pct(before['accuracy'])} / {pct(before['r_at_100p'])}"
        lines.append(
            f"| {k} | {pct(on['accuracy'])} / {pct(on['r_at_100p'])} | {was} | {nn('cosine', k)} | "
            f"{nn('sad_nn', k)} | {100 * sad[k]['accuracy']:.1f} / {100 * sad[k]['r_at_100p']:.1f} | {goal_text} | "
            f"{'yes' if met else 'no'} |"
        )
    lines += ["", "## Whole-route readout", "", _summary_table(summary, sizes, names), ""]
    lines += [
        "SAD on the same places (no learning, velocity given):",
        "",
        "| images | k | accuracy % | R@100P % | AUC-PR % |",
        "|---|---:|---:|---:|---:|",
    ]
    for label, rows in (("patch-normalised 28x28", sad), ("DoG ON/OFF (the network's input)", sad_dog)):
        for k, r in rows.items():
            lines.append(
                f"| {label} | {k} | {100 * r['accuracy']:.1f} | {100 * r['r_at_100p']:.1f} | {100 * r['auc_pr']:.1f} |"
            )
    lines += ["", "## Cost", "", _cost_table(results["cost"], results["networks"], default), ""]
    lines += ["", "## Per module", "", _module_table(results, main), ""]
    first = next(n for n in results["networks"] if n["module_size"] == main)
    curves = {
        f"W+Prob {name}, {size}-place modules": [
            100 * (_find(summary, size, name, "wprob", k) or {"accuracy": {"mean": np.nan}})["accuracy"]["mean"]
            for k in results["ks"]
        ]
        for size in sizes
        for name in (names[0], default, results.get("previous_readout", ""))
        if name in names
    }
    baseline_curves = {"SAD (patch-normalised)": [100 * sad[k]["accuracy"] for k in results["ks"]]}
    if "cosine" in baselines:
        cosine = {r["k"]: r for r in baselines["cosine"]}
        baseline_curves["cosine NN (DoG, no learning)"] = [100 * cosine[k]["accuracy"] for k in results["ks"]]
    route_plot(
        out_dir / f"{stem}.png",
        ks=results["ks"],
        curves=curves | baseline_curves,
        modules={
            r["readout"]: [100 * m["accuracy"] for m in r["modules"]]
            for r in first["readouts"]
            if r["readout"] in (default, results.get("previous_readout", ""))
        },
        module_size=main,
    )
    lines += [f"![route]({stem}.png)", ""]
    return "\n".join(lines)


def _summary_table(summary: list[dict], sizes: list[int], names: list[str]) -> str:
    lines = [
        "| module size | regularisation | readout | accuracy % | R@100P % | AUC-PR % | seeds |",
        "|---:|---|---|---:|---:|---:|---:|",
    ]
    for size in sizes:
        for name in names:
            for row in summary:
                if row["module_size"] != size or row["readout"] != name:
                    continue
                cells = [str(size), name, _label(row["strategy"], row["k"])]
                cells += [pct(row[m]) for m in ("accuracy", "r_at_100p", "auc_pr")] + [str(row["accuracy"]["n"])]
                lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _cost_table(cost: list[dict], networks: list[dict], default: str) -> str:
    lines = [
        "| module size | modules | neurons | seeds | training s per seed (threads) | query run s per seed | "
        "readout s | readout peak MiB | weights MiB | S^R MiB | spikes / query |",
        "|---:|---:|---:|---|---|---|---:|---:|---:|---:|---:|",
    ]
    for c in cost:

        def ms(key: str, c: dict = c) -> str:
            return f"{c[key]['mean']:.1f} ± {c[key]['std']:.1f}"

        mine = [n for n in networks if n["module_size"] == c["module_size"]]
        threads = [str(n.get("trained_on", "")).split(", ")[-1].replace(" torch threads", "") for n in mine]
        training = " / ".join(f"{n['train_seconds']:.0f} ({t})" for n, t in zip(mine, threads, strict=True))
        query = " / ".join(f"{n['query_seconds']:.0f}" for n in mine)
        lines.append(
            f"| {c['module_size']} | {c['modules']} | {c['neurons']} | {', '.join(map(str, c['seeds']))} | "
            f"{training} | {query} | {ms('readout_seconds')} | "
            f"{c['readout_peak_mib']:.0f} | {c['weights_mib']:.1f} | {c['calibration_mib']:.1f} | "
            f"{ms('mean_spikes_per_query')} |"
        )
    return "\n".join(lines) + (
        "\n\nTraining includes calibration (every reference place shown to the whole ensemble) and is the time of "
        "the run that trained the cached network, with the torch/kernel threads it ran with, on this shared 2-core "
        "machine (how loaded it was differs from run to run: docs/experiments.md gives the conditions of these runs); "
        "the query run (the float ensemble on every winter image) likewise. Readout: every strategy at "
        f"k = 1, 5, 10 over the whole route, {default}, velocity given; readout peak: the numpy memory traced "
        "during any readout. Weights: float32 weights and thresholds; S^R as int64."
    )


def _module_table(results: dict, main: int) -> str:
    lines = [
        f"W+Prob k=1 decisions on each region's queries, {main}-place modules: accuracy and the share of decisions "
        "that name a place of the query's own region (the right module won), over modules (min / median / max) "
        "and seeds; silenced = neurons silenced (mean over seeds).",
        "",
        "| regularisation | silenced neurons | accuracy % min / median / max | in-region % min / median / max |",
        "|---|---:|---|---|",
    ]
    mine = [n for n in results["networks"] if n["module_size"] == main]
    for spec in results["readouts"]:
        readouts = [r for n in mine for r in n["readouts"] if r["readout"] == spec["readout"]]
        acc = np.array([m["accuracy"] for r in readouts for m in r["modules"]])
        routed = np.array([m["in_region"] for r in readouts for m in r["modules"]])
        silenced = mean_std(r["silenced"] for r in readouts)

        def spread(a: np.ndarray) -> str:
            return " / ".join(f"{100 * v:.1f}" for v in (a.min(), np.median(a), a.max()))

        lines.append(f"| {spec['readout']} | {silenced.mean:.0f} | {spread(acc)} | {spread(routed)} |")
    return "\n".join(lines)
