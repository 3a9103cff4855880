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

Checkpoints of different configurations (neurons, windows; the seed aside) are kinds of network: each point's
name is then prefixed with its kind ("24 x 100, T=60 r 0.5 (learnt at T=300 r 0.25): margin"), and the table and
the plot show every kind's curve beside the one template point.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from vprsnn_export.config import Config, EarlyConfig, wta_group
from vprsnn_export.data.dataset import Dataset, load_selection
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.data.truth import EXACT
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
        cosine_similarities(reference, images), "cosine", ckpt.reference_place_ids, data.place_ids, options, EXACT
    )
    return {"point": "cosine", "template_macs": macs, "rows": [row.to_dict() for row in rows]}


def kind_of(ckpt: Checkpoint) -> str:
    """The network's kind: modules x neurons, its window and rate, and the window it learnt with where different."""
    cfg = ckpt.config
    modules = module_count(len(ckpt.reference_place_ids), cfg.train.module_size)
    run, learnt = cfg.encoder, cfg.training_encoder
    kind = f"{modules} x {cfg.network.n_neurons}, T={run.timesteps} r {run.rate_scale:g}"
    if learnt != run:
        kind += f" (learnt at T={learnt.timesteps} r {learnt.rate_scale:g})"
    return kind


def run(settings: Settings) -> dict:
    started = time.perf_counter()
    device = resolve_device(settings.device)
    per_network = []
    kinds = []
    for label, ckpt, data in networks(settings):
        kinds.append(kind_of(ckpt))
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
                "kind": kinds[-1],
                "points": points,
            }
        )
    if len(set(kinds)) > 1:  # several kinds of network: every point named with its kind (one template point)
        for net in per_network:
            for p in net["points"]:
                p["point"] = p["point"] if p["point"] == "cosine" else f"{net['kind']}: {p['point']}"
    return {
        "experiment": NAME,
        "networks": per_network,
        "summary": summary(per_network),
        "provenance": provenance(settings, started),
    }


def summary(per_network: list[dict]) -> list[dict]:
    """Per point: the mean cost over the networks that have it and the W+Prob rows' mean ± std (cosine: its own)."""
    names = list(dict.fromkeys(p["point"] for net in per_network for p in net["points"]))
    out = []
    for name in names:
        points = [p for net in per_network for p in net["points"] if p["point"] == name]
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
    points = sorted(results["summary"], key=lambda p: p["point"] == "cosine")  # the template last
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
        f"{n['network']} ({n['places']} places, {n['neurons']} neurons, WTA over the {n['wta_scope']}; {n['kind']})"
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


def split_name(name: str) -> tuple[str, str]:
    """(kind, point) of a point's name; the kind is "" for a single kind of network and for the template."""
    kind, _, short = name.rpartition(": ")
    return kind, short


def marker_of(name: str) -> str:
    """The template a star, scaled windows circles, unscaled windows triangles, early rules squares."""
    short = split_name(name)[1]
    if short == "cosine":
        return "*"
    if short.startswith("T="):
        return "^" if "rate" in short else "o"
    return "s"


def plot(points: list[dict], path: Path) -> Path:
    """W+Prob accuracy at k = 1 and 5 (one panel each) versus synaptic events per query (log x): a colour per kind
    of network, a marker per kind of point, the template as a star."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kinds = list(dict.fromkeys(split_name(p["point"])[0] for p in points if p["point"] != "cosine"))
    colours = {kind: plt.get_cmap("tab10")(i % 10) for i, kind in enumerate(kinds)}
    fig, axes = plt.subplots(1, 2, figsize=(12, 5), sharex=True)
    for ax, k in zip(axes, (1, 5), strict=True):
        for p in points:
            value = _metric(p["rows"], k, "accuracy")
            if value is None:
                continue
            kind, short = split_name(p["point"])
            x, y = p["cost"]["synaptic_events"], 100 * value["mean"]
            marker = marker_of(p["point"])
            colour = "black" if marker == "*" else colours[kind]
            ax.scatter(x, y, color=colour, marker=marker, s=120 if marker == "*" else 40)
            ax.annotate(short, (x, y), fontsize=6, xytext=(3, 3), textcoords="offset points")
        ax.set_xscale("log")
        ax.set_xlabel("synaptic events per query (template: multiply-adds)")
        ax.set_ylabel(f"W+Prob accuracy % at k={k}")
        ax.set_title(f"Accuracy versus events per query, k={k}")
        ax.grid(True, alpha=0.3)
    ax = axes[-1]
    for kind in kinds:
        ax.scatter([], [], color=colours[kind], label=kind or "the network")
    ax.scatter([], [], color="grey", marker="o", label="window T (rate scaled: the input spikes kept)")
    ax.scatter([], [], color="grey", marker="^", label="window T (rate unchanged)")
    ax.scatter([], [], color="grey", marker="s", label="early decision")
    ax.scatter([], [], color="black", marker="*", s=120, label="template (cosine; x: multiply-adds)")
    outside_legend(ax)
    return save_figure(fig, path)
