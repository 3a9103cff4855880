"""A two-stage region -> place decision, probed in float (issue 30; research log §14).

For the first ``t1`` steps a query runs on the whole ensemble (one WTA over every module, as deployed); then
only the ``R`` modules with the most output spikes so far (ties: the larger summed input current of a module's
best neuron) keep receiving input, every other neuron is held at V = 0 and cannot fire. Synaptic events per
query = input spikes of steps < t1 x all neurons + input spikes of steps >= t1 x R n neurons. The readout is
W+Prob with the checkpoint's own S^R (calibrated on whole runs). ``t1 x R`` = ``T x M`` is the network as deployed
(the control row). The float torch step of ``network.dynamics.wta_step``, one chunk of queries at a time.

    python tools/two_stage_probe.py CKPT --data ../shared/data/nordland_64x32_summer_winter \
        --stages 80x24,10x1,10x2,20x1,20x2,20x6,40x4 [--query winter] [--threads 1]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

import vprsnn_export as vx
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.network.dynamics import wta_step
from vprsnn_export.readout.aggregation import aggregate
from vprsnn_export.readout.metrics import is_correct, pr_metrics, predicted_place_ids
from vprsnn_export.readout.scoring import Readout
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.readout.strategies import decide

CHUNK = 200


def two_stage_counts(
    spikes: torch.Tensor, weights: torch.Tensor, theta: torch.Tensor, beta: float, group: int, t1: int, regions: int
) -> tuple[np.ndarray, np.ndarray]:
    """Spike counts (N, neurons) and synaptic events per query (N,) of the two-stage run."""
    n_neurons = weights.shape[1]
    modules = n_neurons // group
    counts = np.zeros((spikes.shape[0], n_neurons), np.int64)
    events = np.zeros(spikes.shape[0])
    for start in range(0, spikes.shape[0], CHUNK):
        x = spikes[start : start + CHUNK].float()
        b, steps = x.shape[0], x.shape[1]
        current = torch.matmul(x, weights)
        voltage = torch.zeros(b, n_neurons)
        fired_total = torch.zeros(b, n_neurons)
        allowed = torch.ones(b, n_neurons, dtype=torch.bool)
        for t in range(steps):
            if t == t1 and regions < modules:
                tie_break = 1e-3 * current[:, :t1].sum(1).reshape(b, modules, group).max(2).values
                per_module = fired_total.reshape(b, modules, group).sum(2) + tie_break
                chosen = torch.zeros(b, modules, dtype=torch.bool)
                chosen.scatter_(1, per_module.topk(regions, dim=1).indices, True)
                allowed = chosen.repeat_interleave(group, dim=1)
                voltage = voltage.masked_fill(~allowed, 0.0)
            step_current = current[:, t].masked_fill(~allowed, 0.0)
            voltage, fired, _ = wta_step(voltage, step_current, theta.masked_fill(~allowed, float("inf")), beta, True)
            fired_total += fired
        inputs = x.sum(dim=2)
        reached = regions * group if regions < modules else n_neurons
        events[start : start + b] = (inputs[:, :t1].sum(1) * n_neurons + inputs[:, t1:].sum(1) * reached).numpy()
        counts[start : start + b] = fired_total.numpy()
    return counts, events


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--data", required=True)
    parser.add_argument("--query", default="winter")
    parser.add_argument("--stages", required=True, help="t1xR,... (steps on the whole ensemble x regions kept)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    vx.set_threads(args.threads)
    ckpt = vx.load_checkpoint(args.checkpoint)
    cfg, ids = ckpt.config, ckpt.reference_place_ids
    data = vx.load_dataset(args.data, [args.query], cfg.preprocess, subset=ids)
    spikes = query_spikes(data.traversal(args.query), ids, args.query, cfg)
    weights = torch.as_tensor(ckpt.weights, dtype=torch.float32)
    theta = torch.as_tensor(ckpt.thresholds, dtype=torch.float32)
    readout = Readout.of(ckpt.calibration, cfg, SequenceOptions(ks=(1,)))
    for stage in args.stages.split(","):
        t1, regions = (int(v) for v in stage.split("x"))
        began = time.perf_counter()
        counts, events = two_stage_counts(spikes, weights, theta, cfg.network.beta, cfg.network.n_neurons, t1, regions)
        wprob = readout.scores(counts)["wprob"]
        cells = []
        for k in (1, 5, 10):
            pred, conf = decide(aggregate(wprob, k, 1.0, "product"), "wprob")
            m = pr_metrics(is_correct(predicted_place_ids(pred, ids), ids, 0), conf)
            cells.append(f"k={k}: {100 * m['accuracy']:.1f} / {100 * m['r_at_100p']:.1f}")
        seconds = time.perf_counter() - began
        print(
            f"t1={t1} R={regions}: {events.mean() / 1e6:.2f} M events / query  "
            + "  ".join(cells)
            + f"  ({seconds:.0f} s)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
