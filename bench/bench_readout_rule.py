"""The NIR readout rule (``targets.nir_target.apply_readout_rule``) against the dense form it replaced, by route length.

The rule turns a float NIR consumer's WTA-off spikes into the network's raster; ``export --check`` and
``verify --targets nir`` apply it to every consumer's output. The dense form computes every step's currents
of every neuron in float64 (``spikes @ W^T``: steps x neurons); the current one only the contested steps'
(two or more candidates in a WTA group), summed over the spiking inputs (an embedding bag), 4096 steps at a
time. Both run here side by side on the same synthetic graph (a lean route: one neuron per place, modules of
100, 1568 inputs, 3 % input spikes per step, 40 % of neurons over threshold as measured on the demo's route),
for route lengths 2,400 and 10,000 places, and must give the same raster. Printed: seconds of each (best of
``--repeats``), their ratio, and the largest array each allocates (the dense currents against one chunk's).

    python bench/bench_readout_rule.py --threads 1 [--places 2400,10000] [--queries 16] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import time
from types import SimpleNamespace

import numpy as np
import torch

from vprsnn_export.targets.nir_target import READOUT_RULE, apply_readout_rule
from vprsnn_export.threads import set_threads

CHUNK = 4096  # apply_readout_rule's steps per chunk


def dense_rule(graph, spikes: torch.Tensor, candidates: torch.Tensor) -> torch.Tensor:
    """The rule as it was computed before (c644f01): every step's int64 scores, masked, argmax per group."""
    meta = graph.metadata
    weight = np.asarray(graph.nodes["linear"].weight)
    group = json.loads(meta["readout_rule"])["group_size"]
    flat = spikes.reshape(-1, spikes.shape[-1])
    currents = flat.to(torch.float64) @ torch.as_tensor(weight.T, dtype=torch.float64)
    multipliers = torch.as_tensor(np.asarray(meta["wta_score_multiplier"]), dtype=torch.int64)
    score = currents.round().to(torch.int64) * multipliers
    masked = torch.where(candidates.reshape(score.shape), score, torch.iinfo(torch.int64).min)
    grouped = masked.reshape(masked.shape[0], -1, group)
    winner = grouped.argmax(dim=2, keepdim=True)
    raster = torch.zeros(grouped.shape, dtype=torch.bool).scatter_(2, winner, True)
    raster &= candidates.reshape(grouped.shape).to(torch.bool).any(dim=2, keepdim=True)
    return raster.reshape(candidates.shape)


def route_graph(places: int, inputs: int, rng: np.random.Generator):
    """A fixed-point graph's readout inputs: 4-bit mantissas (inputs x places, one neuron per place), modules
    of 100, one WTA group over the ensemble (the default), random score multipliers."""
    weight = rng.integers(0, 16, (places, inputs)).astype(np.float32)  # linear.weight is (neurons, inputs)
    rule = {"name": READOUT_RULE, "version": 2, "group_size": places}
    metadata = {
        "readout_rule": json.dumps(rule),
        "kind": "fixed-point",
        "wta_score_multiplier": rng.integers(1, 1 << 16, places).tolist(),
    }
    return SimpleNamespace(metadata=metadata, nodes={"linear": SimpleNamespace(weight=weight)})


def best(function, repeats: int) -> tuple[float, torch.Tensor]:
    times, out = [], None
    for _ in range(repeats):
        began = time.perf_counter()
        out = function()
        times.append(time.perf_counter() - began)
    assert out is not None
    return min(times), out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--places", default="2400,10000", help="route lengths (neurons = places)")
    parser.add_argument("--queries", type=int, default=16, help="presentations (export --check's default: 16)")
    parser.add_argument("--timesteps", type=int, default=80, help="steps per presentation (lean: 80)")
    parser.add_argument("--inputs", type=int, default=1568)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    set_threads(args.threads)
    rng = np.random.default_rng(0)
    print(f"{args.queries} queries x {args.timesteps} steps, {args.inputs} inputs, {args.threads} torch thread(s)")
    print(f"{'places':>7}  {'dense s':>8}  {'rule s':>7}  {'dense/rule':>10}  {'dense MB':>9}  {'chunk MB':>9}  same")
    for places in (int(p) for p in args.places.split(",")):
        graph = route_graph(places, args.inputs, rng)
        spikes = torch.as_tensor(rng.random((args.queries, args.timesteps, args.inputs)) < 0.03, dtype=torch.uint8)
        candidates = torch.as_tensor(rng.random((args.queries, args.timesteps, places)) < 0.4)
        dense_s, dense = best(lambda: dense_rule(graph, spikes, candidates), args.repeats)
        rule_s, ruled = best(lambda: apply_readout_rule(graph, spikes, candidates), args.repeats)
        steps = args.queries * args.timesteps
        dense_mb, chunk_mb = 8 * steps * places / 1e6, 8 * min(steps, CHUNK) * places / 1e6
        same = bool(torch.equal(dense, ruled))
        print(
            f"{places:>7}  {dense_s:8.3f}  {rule_s:7.3f}  {dense_s / rule_s:10.1f}  {dense_mb:9.1f}  {chunk_mb:9.1f}  {same}"
        )
        if not same:
            return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
