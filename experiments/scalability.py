"""Figure: AUC-PR (W+Prob, k=1) vs number of places N over sliding windows of consecutive places."""

from __future__ import annotations

import time
from pathlib import Path

from vprsnn_export.stats import mean_std

from .common import Settings, load, provenance, trained_checkpoint
from .plots import line_plot
from .query import evaluate_query

NAME = "scalability"
DESCRIPTION = (
    "AUC-PR and accuracy (W+Prob, k=1) vs N in {25, 50, 100, 200, 400}, windows of consecutive places, beside "
    "cosine nearest neighbour on the network's own input (no learning)"
)
METRICS = (("AUC-PR", "auc_pr"), ("accuracy", "accuracy"), ("R@100P", "r_at_100p"))
FULL_SIZES = (25, 50, 100, 200, 400)
FULL_STARTS = (500, 1500)
QUICK_SIZES = (10, 20)
QUICK_STARTS = (0, 4)


def run(settings: Settings) -> dict:
    started = time.perf_counter()
    sizes, starts = (QUICK_SIZES, QUICK_STARTS) if settings.quick else (FULL_SIZES, FULL_STARTS)
    seed = settings.seeds[0]
    points = []
    for n in sizes:
        windows = []
        for start in starts:
            cfg = settings.config(seed)
            data = load(settings, "consecutive", cfg, places=f"{start}:{n}")
            ckpt = trained_checkpoint(settings, data, cfg, f"window{start}-{n}")
            result = evaluate_query(settings, ckpt, data, cfg, baselines=True)
            row = next(r for r in result.rows if r["strategy"] == "wprob")
            cosine = next(r for r in result.rows if r["strategy"] == "cosine" and r["k"] == 1)
            windows.append({"start": start, **row, "cosine": cosine})
        points.append(
            {
                "n_places": n,
                "windows": windows,
                **{key: mean_std(w[key] for w in windows).to_dict() for _, key in METRICS},
                "cosine": {key: mean_std(w["cosine"][key] for w in windows).to_dict() for _, key in METRICS},
            }
        )
    return {"experiment": NAME, "seed": seed, "points": points, "provenance": provenance(settings, started)}


def render(results: dict, out_dir: Path, stem: str = NAME) -> str:
    points = results["points"]
    x = [p["n_places"] for p in points]
    series = {
        label: ([100 * p[key]["mean"] for p in points], [100 * p[key]["std"] for p in points]) for label, key in METRICS
    }
    with_cosine = all("cosine" in p for p in points)  # pages written before the baseline was measured lack it
    if with_cosine:
        series["cosine NN accuracy"] = (
            [100 * p["cosine"]["accuracy"]["mean"] for p in points],
            [100 * p["cosine"]["accuracy"]["std"] for p in points],
        )
    line_plot(
        out_dir / f"{stem}.png",
        x,
        series,
        xlabel="reference places N",
        ylabel="% (W+Prob, k=1)",
        title="Scalability: sliding windows of consecutive places",
        log_x=True,
    )
    header = "| N | windows | AUC-PR % | accuracy % | R@100P % |"
    if with_cosine:
        header += " cosine NN AUC-PR % | cosine NN accuracy % | cosine NN R@100P % |"
    lines = [header, "|" + "---:|" * (header.count("|") - 1)]
    for p in points:
        blocks = [p, p["cosine"]] if with_cosine else [p]
        lines.append(
            f"| {p['n_places']} | {len(p['windows'])} | "
            + " | ".join(f"{100 * b[k]['mean']:.1f} ± {100 * b[k]['std']:.1f}" for b in blocks for _, k in METRICS)
            + " |"
        )
    return (
        "\n".join(lines) + f"\n\nOne network (seed {results['seed']}) per window; ± is over windows "
        f"(starts {', '.join(str(w['start']) for w in points[0]['windows'])}).\n\n![scalability]({stem}.png)\n"
    )
