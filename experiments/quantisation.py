"""Every metric vs weight bit width 8..2, per-tensor vs per-neuron, k=1 and k=5, over seeds."""

from __future__ import annotations

import time
from pathlib import Path

from vprsnn_export.device import resolve_device
from vprsnn_export.export.quantize import QuantiseOptions
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.deployment import deploy
from vprsnn_export.runtime.evaluation import evaluate_fixed_point, evaluate_float

from .common import Settings, consecutive_networks, provenance, rows_table, summarise_rows
from .plots import line_plot

NAME = "quantisation"
DESCRIPTION = (
    "accuracy and R@100P (all strategies k=1, W+Prob k=5) vs weight bits 8..2, per-tensor vs "
    "per-neuron scales (max-abs), deployed recalibration on the integer simulator, 100 consecutive places"
)
BITS = (8, 6, 4, 3, 2)
SCALINGS = {"per-neuron": True, "per-tensor": False}


def run(settings: Settings) -> dict:
    started = time.perf_counter()
    device = resolve_device(settings.device)
    per_seed = []
    for seed, _cfg, data, ckpt in consecutive_networks(settings):
        options = SequenceOptions(ks=(1, 5))
        query = data.traversal(settings.query)
        float_rows = evaluate_float(ckpt, query, data.place_ids, settings.query, options, device=device).rows
        rows = [dict(r, bits="float", scaling="float", seed=seed, saturations=0) for r in float_rows]
        reference = {settings.reference: data.traversal(settings.reference)}
        for scaling, per_neuron in SCALINGS.items():
            for bits in BITS:
                scheme = QuantiseOptions(per_neuron=per_neuron)
                model = deploy(ckpt, "experiment", bits, scheme, reference_images=reference, device=device)
                result = evaluate_fixed_point(model, query, data.place_ids, settings.query, options, device=device)
                rows += [
                    dict(
                        row_without_calibration(r),
                        bits=str(bits),
                        scaling=scaling,
                        seed=seed,
                        saturations=result.saturations,
                    )
                    for r in result.rows
                    if r["calibration"] == "deployed"
                ]
        per_seed.append(rows)
    return {
        "experiment": NAME,
        "summary": summarise_rows(per_seed, ("scaling", "bits", "strategy", "k")),
        "per_seed": per_seed,
        "provenance": provenance(settings, started),
    }


def row_without_calibration(row: dict) -> dict:
    return {key: value for key, value in row.items() if key != "calibration"}


def render(results: dict, out_dir: Path, stem: str = NAME) -> str:
    summary = results["summary"]

    def pick(scaling, strategy, k):
        return {r["bits"]: r for r in summary if r["scaling"] == scaling and r["strategy"] == strategy and r["k"] == k}

    float_k = {k: pick("float", "wprob", k)["float"] for k in (1, 5)}
    series, baselines = {}, {}
    for k in (1, 5):
        for metric, label in (("accuracy", "acc"), ("r_at_100p", "R@100P")):
            baselines[f"float W+Prob k={k} {label}"] = 100 * float_k[k][metric]["mean"]
            for scaling in SCALINGS:
                rows = pick(scaling, "wprob", k)
                series[f"{scaling} k={k} {label}"] = (
                    [100 * rows[str(b)][metric]["mean"] for b in BITS],
                    [100 * rows[str(b)][metric]["std"] for b in BITS],
                )
    line_plot(
        out_dir / f"{stem}.png",
        list(BITS),
        series,
        xlabel="weight bits",
        ylabel="% (W+Prob)",
        title="Quantisation: W+Prob vs weight bits (grey lines: float)",
        baselines=baselines,
    )
    table = rows_table([r for r in summary if r["strategy"] == "wprob"], ("scaling", "bits", "strategy", "k"))
    full = rows_table([r for r in summary if r["strategy"] != "wprob"], ("scaling", "bits", "strategy", "k"))
    return f"## W+Prob\n\n{table}\n\n![quantisation]({stem}.png)\n\n## Standard and Weighted, k = 1\n\n{full}\n"
