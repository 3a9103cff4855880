"""Accuracy versus synaptic events per query: the early decision and shorter windows beside the template (#30).

For each network (``--checkpoint FILE``, repeatable; else one trained per seed on the consecutive places) and
its query traversal, every point runs the float network and reads it out like ``evaluate`` (W+Prob at k = 1, 5,
10 on the whole route, the ensemble's region regularisation included), and counts the cost per query
(:mod:`vprsnn_export.network.cost`):

* ``T=300`` (the network's own window): every query runs all T steps;
* ``margin``, ``spikes K``, ``margin + spikes K``: the early decision (:mod:`vprsnn_export.readout.early`) on the
  same runs (the counts of the first T_q steps, from the recorded raster);
* ``T=T'``: a shorter window, the rate scaled by T / T' to keep the expected input spikes, and ``T=T', rate r``
  with the rate unchanged (input spikes and events cut by T' / T); inference only: the same weights and
  thresholds, calibrated again at T';
* ``cosine``: the template matcher on the same images (nnz(x_q) x places multiply-adds).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from vprsnn_export.config import Config, EarlyConfig, wta_group
from vprsnn_export.data.dataset import Dataset, load_selection
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.device import resolve_device
from vprsnn_export.io.checkpoint import Checkpoint, load_checkpoint
from vprsnn_export.network.cost import CostSummary, query_cost
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.network.modules import module_count
from vprsnn_export.readout.assignment import standard_assignment
from vprsnn_export.readout.baseline import cosine_similarities
from vprsnn_export.readout.early import EarlyDecision, early_decision
from vprsnn_export.readout.regions import regularised_calibration
from vprsnn_export.readout.scoring import ensemble_layout, nearest_neighbour_rows, readout_rows
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.targets.loihi_budget import core_budget, query_estimate
from vprsnn_export.trainer.calibrate import calibrate

from .common import Settings, consecutive_networks, provenance, summarise_rows
from .plots import outside_legend, save_figure

NAME = "cost"
DESCRIPTION = (
    "accuracy (W+Prob k=1, 5, 10) and R@100P versus synaptic events per query: the network's window, the early "
    "decision (margin, spike-count rules), shorter windows with the rate scaled, and the template matcher"
)
KS = (1, 5, 10)
WINDOW_FRACTIONS = (2 / 3, 1 / 2, 1 / 3, 1 / 6)  # of the network's T: 200, 150, 100, 50 at T = 300
SPIKE_FRACTIONS = (1 / 30, 1 / 12, 1 / 6)  # output spikes K as a share of T: 10, 25, 50 at T = 300
CHUNK = 64  # queries whose rasters are recorded at once
ESTIMATE_BITS = 8  # the weight width of the Loihi core budget behind the estimate (k neurons per core)
ESTIMATES = ("energy_uj", "latency_ms")


def networks(settings: Settings):
    """(label, checkpoint, data) per network: the given checkpoints on their own places, else one per seed."""
    if settings.checkpoints:
        for path in settings.checkpoints:
            ckpt = load_checkpoint(path)
            traversals = [*ckpt.reference_traversals, settings.query]
            data = load_selection(ckpt.data, traversals, ckpt.config.preprocess, progress=settings.progress)
            yield Path(path).stem, ckpt, data
        return
    for seed, _, data, ckpt in consecutive_networks(settings):
        yield f"seed {seed}", ckpt, data


def rules(timesteps: int) -> dict[str, EarlyConfig]:
    """The early-decision rules measured at a window of ``timesteps``."""
    ks = sorted({max(1, round(timesteps * f)) for f in SPIKE_FRACTIONS})
    out = {"margin": EarlyConfig(margin=True)}
    out.update({f"spikes {k}": EarlyConfig(spikes=k) for k in ks})
    out[f"margin + spikes {ks[-1]}"] = EarlyConfig(margin=True, spikes=ks[-1])
    return out


def point(name: str, timesteps: int, rate: float, cost: CostSummary, rows: list[dict]) -> dict:
    return {"point": name, "timesteps": timesteps, "rate_scale": rate, "cost": cost.to_dict(), "rows": rows}


def readout(ckpt: Checkpoint, calibration: np.ndarray, counts: np.ndarray, data: Dataset) -> list[dict]:
    options = SequenceOptions(ks=tuple(k for k in KS if k <= len(data.place_ids)))
    rows = readout_rows(calibration, counts, ckpt.reference_place_ids, data.place_ids, options, ckpt.config)
    return [row.to_dict() for row in rows]


def early_points(ckpt: Checkpoint, data: Dataset, query: str, network: FloatNetwork) -> list[dict]:
    """The network's own window and every early rule, from one recorded run of the queries (chunk by chunk)."""
    cfg = ckpt.config
    images = data.traversal(query)
    spikes = query_spikes(images, data.place_ids, query, cfg)
    layout = ensemble_layout(cfg, len(ckpt.reference_place_ids))
    sr = ckpt.calibration if layout is None else regularised_calibration(ckpt.calibration, layout)[0]
    votes = standard_assignment(sr)
    neurons = int(ckpt.weights.shape[1])
    group = wta_group(cfg, neurons)
    timesteps = cfg.encoder.timesteps
    chosen = {f"T={timesteps}": EarlyConfig(), **rules(timesteps)}
    decisions: dict[str, list[EarlyDecision]] = {name: [] for name in chosen}
    for start in range(0, len(images), CHUNK):  # one network run per chunk, every rule on its raster
        run = network.run(spikes[start : start + CHUNK], record=True)
        assert run.raster is not None  # recorded
        raster = run.raster.numpy()
        for name, rule in chosen.items():
            decisions[name].append(early_decision(raster, votes, group, rule))
    out = []
    for name, parts in decisions.items():
        steps = np.concatenate([p.steps for p in parts])
        counts = np.concatenate([p.counts for p in parts])
        cost = query_cost(spikes, neurons, places=len(ckpt.reference_place_ids), images=images, steps=steps)
        rows = readout(ckpt, ckpt.calibration, counts, data)
        out.append(point(name, timesteps, cfg.encoder.rate_scale, cost.summary(), rows))
    return out


def window_points(ckpt: Checkpoint, data: Dataset, query: str, device: torch.device) -> list[dict]:
    """Shorter windows T': the rate scaled by T / T' (the input spikes kept) and the rate unchanged (the input spikes
    cut by T' / T); the same network, calibrated and queried at T'."""
    cfg = ckpt.config
    timesteps, rate = cfg.encoder.timesteps, cfg.encoder.rate_scale
    images = data.traversal(query)
    references = {name: data.traversal(name) for name in ckpt.reference_traversals}
    out = []
    windows = sorted({max(1, round(timesteps * f)) for f in WINDOW_FRACTIONS}, reverse=True)
    for window, scaled in [(w, rate * timesteps / w) for w in windows] + [(w, rate) for w in windows]:
        name = f"T={window}" if scaled != rate else f"T={window}, rate {rate:g}"
        short: Config = cfg.replace(**{"encoder.timesteps": window, "encoder.rate_scale": scaled})
        network = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, short, device)
        calibration = calibrate(network.counts, references, data.place_ids, short)
        spikes = query_spikes(images, data.place_ids, query, short)
        counts = network.counts(spikes).numpy()
        cost = query_cost(spikes, int(ckpt.weights.shape[1]), places=len(ckpt.reference_place_ids), images=images)
        out.append(point(name, window, scaled, cost.summary(), readout(ckpt, calibration, counts, data)))
    return out


def template_point(ckpt: Checkpoint, data: Dataset, query: str, macs: float) -> dict:
    """Cosine nearest neighbour on the same images (k frames summed along the diagonal, like evaluate --baseline)."""
    images = data.traversal(query)
    reference = np.mean([data.traversal(name) for name in ckpt.reference_traversals], axis=0)
    options = SequenceOptions(ks=tuple(k for k in KS if k <= len(data.place_ids)))
    rows = nearest_neighbour_rows(
        cosine_similarities(reference, images), "cosine", ckpt.reference_place_ids, data.place_ids, options
    )
    return {"point": "cosine", "template_macs": macs, "rows": [row.to_dict() for row in rows]}


def run(settings: Settings) -> dict:
    started = time.perf_counter()
    device = resolve_device(settings.device)
    per_network = []
    for label, ckpt, data in networks(settings):
        network = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, ckpt.config, device)
        network.progress = settings.progress
        points = early_points(ckpt, data, settings.query, network)
        points += window_points(ckpt, data, settings.query, device)
        budget = core_budget(
            module_count(len(ckpt.reference_place_ids), ckpt.config.train.module_size),
            ckpt.config.network.n_neurons,
            ckpt.config.network.n_inputs,
            ESTIMATE_BITS,
        )
        for p in points:
            estimate = query_estimate(CostSummary.from_dict(p["cost"]), budget)
            p["loihi_estimate"] = {"energy_uj": estimate.energy_uj, "latency_ms": estimate.latency_ms}
        points.append(template_point(ckpt, data, settings.query, points[0]["cost"]["template_macs"]))
        per_network.append(
            {
                "network": label,
                "places": len(data.place_ids),
                "neurons": int(ckpt.weights.shape[1]),
                "wta_scope": ckpt.config.network.wta_scope,
                "points": points,
            }
        )
    return {
        "experiment": NAME,
        "networks": per_network,
        "summary": summary(per_network),
        "provenance": provenance(settings, started),
    }


def summary(per_network: list[dict]) -> list[dict]:
    """Per point: the mean cost over networks and the W+Prob rows' mean ± std (cosine: its own rows)."""
    names = [p["point"] for p in per_network[0]["points"]]
    out = []
    for name in names:
        points = [next(p for p in net["points"] if p["point"] == name) for net in per_network]
        keep = [[r for r in p["rows"] if r["strategy"] in ("wprob", "cosine")] for p in points]
        rows = summarise_rows(keep, ("strategy", "k"))
        if name == "cosine":
            cost = {"synaptic_events": float(np.mean([p["template_macs"] for p in points])), "steps": 1.0}
        else:
            cost = {key: float(np.mean([p["cost"][key] for p in points])) for key in points[0]["cost"]}
            cost.update({key: float(np.mean([p["loihi_estimate"][key] for p in points])) for key in ESTIMATES})
        out.append({"point": name, "cost": cost, "rows": rows})
    return out


def _metric(row_list: list[dict], k: int, metric: str) -> dict | None:
    return next((r[metric] for r in row_list if r["k"] == k), None)


def render(results: dict, out_dir: Path, stem: str = NAME) -> str:
    points = results["summary"]
    plot(points, out_dir / f"{stem}.png")
    head = (
        "| point | steps | input spikes | synaptic events (template: multiply-adds) | x template | "
        + " | ".join(f"acc k={k} %" for k in KS)
        + f" | R@100P k=5 % | Loihi 1 estimate ({ESTIMATE_BITS}-bit): uJ, ms |"
    )
    lines = [head, "|" + "---|" * (5 + len(KS) + 2)]
    template = next(p["cost"]["synaptic_events"] for p in points if p["point"] == "cosine")
    for p in points:
        cost = p["cost"]
        cells = [
            p["point"],
            f"{cost['steps']:.1f}" if p["point"] != "cosine" else "-",
            f"{cost['input_spikes']:,.0f}" if "input_spikes" in cost else "-",
            f"{cost['synaptic_events']:,.0f}",
            f"{cost['synaptic_events'] / template:.1f}",
        ]
        for k in KS:
            value = _metric(p["rows"], k, "accuracy")
            cells.append("-" if value is None else f"{100 * value['mean']:.1f} ± {100 * value['std']:.1f}")
        r100 = _metric(p["rows"], 5, "r_at_100p")
        cells.append("-" if r100 is None else f"{100 * r100['mean']:.1f} ± {100 * r100['std']:.1f}")
        cells.append(f"{cost['energy_uj']:,.0f}, {cost['latency_ms']:.2f}" if "energy_uj" in cost else "-")
        lines.append("| " + " | ".join(cells) + " |")
    nets = ", ".join(
        f"{n['network']} ({n['places']} places, {n['neurons']} neurons, WTA over the {n['wta_scope']})"
        for n in results["networks"]
    )
    return (
        f"Networks: {nets}. Mean over networks (± std where there are several); synaptic events = input spikes "
        "x every neuron (each input reaches all M n neurons); the template's cost is nnz(query) x places "
        "multiply-adds. The Loihi 1 column is an **estimate** from published pre-silicon per-operation figures "
        "(docs/targets.md section 2.6: 23.6 pJ per synaptic op, 81 pJ per neuron update; dynamic energy only).\n\n"
        + "\n".join(lines)
        + f"\n\n![accuracy versus events]({stem}.png)\n"
    )


def marker_of(name: str) -> str:
    """The template a star, scaled windows circles, unscaled windows triangles, early rules squares."""
    if name == "cosine":
        return "*"
    if name.startswith("T="):
        return "^" if "rate" in name else "o"
    return "s"


def plot(points: list[dict], path: Path) -> Path:
    """W+Prob accuracy at k = 1 and 5 versus synaptic events per query (log x), the template as a star."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    for k, colour in zip((1, 5), ("tab:blue", "tab:orange"), strict=True):
        for p in points:
            value = _metric(p["rows"], k, "accuracy")
            if value is None:
                continue
            x, y = p["cost"]["synaptic_events"], 100 * value["mean"]
            marker = marker_of(p["point"])
            ax.scatter(x, y, color=colour, marker=marker, s=120 if marker == "*" else 40)
            ax.annotate(p["point"], (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
        ax.scatter([], [], color=colour, label=f"k={k}")
    ax.scatter([], [], color="grey", marker="o", label="window T (rate scaled: the input spikes kept)")
    ax.scatter([], [], color="grey", marker="^", label="window T (rate unchanged)")
    ax.scatter([], [], color="grey", marker="s", label="early decision")
    ax.scatter([], [], color="grey", marker="*", s=120, label="template (cosine; x: multiply-adds)")
    ax.set_xscale("log")
    ax.set_xlabel("synaptic events per query (template: multiply-adds)")
    ax.set_ylabel("W+Prob accuracy %")
    ax.set_title("Accuracy versus events per query")
    outside_legend(ax)
    ax.grid(True, alpha=0.3)
    return save_figure(fig, path)
