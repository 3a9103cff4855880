"""Where the deployed network's spikes leave the float network's: the table of docs/fixed-point.md section 8.

    python bench/precision_sources.py CKPT [--data PLACES.csv] [--subset S.csv] [--query winter] [--bits 8,4,2]

The integer network differs from the float one by four roundings: the weight mantissas q_ij s_j,
the threshold mantissas theta_int_j s_j, the 12-bit decay beta -> (4096 - dv) / 4096 and the
decay's truncation toward zero. This script runs the float dynamics (float64, one (N, neurons)
step at a time) with each rounding added in turn and prints, per bit width, the fraction of
(query, step) pairs whose WTA winner equals the float network's (the `winner_agreement` of
`verify`), how the differing steps split (same candidate set, i.e. only the WTA order differs,
or a different candidate set), how often the float network's top-2 current margin is below one
weight step s_j of its winner, and the agreement of b = 8..12-bit round-to-nearest weights
(float dynamics otherwise), and the agreement when uniform noise of one (and of a quarter) 8-bit
weight step replaces the rounding. The last row of each width is the integer simulator itself, and the
emulation is checked equal to it step for step.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable

import numpy as np
import torch

from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.export.model import DECAY_BITS
from vprsnn_export.export.quantize import QuantiseOptions, quantize_checkpoint
from vprsnn_export.io.checkpoint import load_checkpoint
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.targets.intsim import IntegerNetwork


def winners(raster: np.ndarray) -> np.ndarray:
    """(N, T) index of the neuron that spiked at each step, -1 when none (one WTA group)."""
    won = raster.argmax(axis=2)
    won[~raster.any(axis=2)] = -1
    return won


def run(
    currents: np.ndarray, theta: np.ndarray, decay: Callable[[np.ndarray], np.ndarray]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """V = decay(V) + I[t]; C = V > theta; winner = first argmax of I over C; V[C] = 0.

    Returns winners (N, T), candidate sets (N, T, neurons) and the top-2 margin of I over C (N, T).
    """
    n, steps, neurons = currents.shape
    voltage = np.zeros((n, neurons))
    won = np.full((n, steps), -1)
    cand = np.zeros((n, steps, neurons), dtype=bool)
    margin = np.full((n, steps), np.inf)
    for t in range(steps):
        voltage = decay(voltage) + currents[:, t]
        cand[:, t] = voltage > theta
        score = np.where(cand[:, t], currents[:, t], -np.inf)
        top2 = np.sort(score, axis=1)[:, -2:]
        won[:, t] = np.where(cand[:, t].any(axis=1), score.argmax(axis=1), -1)
        with np.errstate(invalid="ignore"):
            margin[:, t] = top2[:, 1] - top2[:, 0]
        voltage[cand[:, t]] = 0
    return won, cand, margin


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--data", default="../shared/data/nordland_64x32_summer_winter/places.csv")
    parser.add_argument("--subset", default="../shared/data/nordland_64x32_summer_winter/subset_100_places.csv")
    parser.add_argument("--query", default="winter")
    parser.add_argument("--bits", default="8,4,2")
    args = parser.parse_args()
    torch.set_num_threads(1)
    ckpt = load_checkpoint(args.checkpoint)
    data = load_dataset(args.data, [args.query], ckpt.config.preprocess, subset=args.subset)
    spikes = query_spikes(data.traversal(args.query), data.place_ids, args.query, ckpt.config)
    inputs = spikes.numpy().astype(np.float64)
    beta = ckpt.config.network.beta
    weights, theta = ckpt.weights.astype(np.float64), ckpt.thresholds.astype(np.float64)
    float_net = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, ckpt.config, torch.device("cpu"))
    reference = winners(float_net.run(spikes, record=True).raster.numpy())
    currents = inputs @ weights
    exact, exact_cand, margin = run(currents, theta, lambda v: beta * v)
    out: dict[str, object] = {"float64_equals_float32": float((exact == reference).mean())}
    for bits in (int(b) for b in args.bits.split(",")):
        model = quantize_checkpoint(ckpt, "0" * 64, bits, QuantiseOptions())
        scale = np.ldexp(model.scale_multiplier.astype(np.float64), model.scale_exponent)
        keep = (1 << DECAY_BITS) - model.decay_dv
        unit = scale / 64  # the integer voltage's unit per neuron
        q_currents = inputs @ (model.weight_mantissa * scale)
        q_theta = model.threshold * scale
        steps = {
            "12-bit decay only": run(currents, theta, lambda v: v * keep / (1 << DECAY_BITS))[0],
            "weights": run(q_currents, theta, lambda v: beta * v)[0],
            "+ thresholds": run(q_currents, q_theta, lambda v: beta * v)[0],
            "+ 12-bit decay": run(q_currents, q_theta, lambda v: v * keep / (1 << DECAY_BITS))[0],
        }
        emulated, cand, _ = run(
            q_currents, q_theta, lambda v: np.floor(np.round(v / unit) * keep / (1 << DECAY_BITS)) * unit
        )
        steps["+ truncation toward zero"] = emulated
        integer = winners(IntegerNetwork(model).run(spikes, record=True).raster.numpy())
        differ = integer != exact
        same_cand = (cand == exact_cand).all(axis=2)
        step = np.where(exact >= 0, scale[np.maximum(exact, 0)], np.nan)
        out[f"{bits} bits"] = {
            **{name: float((won == reference).mean()) for name, won in steps.items()},
            "integer simulator": float((integer == reference).mean()),
            "emulation equals the integer simulator": float((emulated == integer).mean()),
            "differing, same candidates (WTA order)": float((differ & same_cand).mean()),
            "differing, other candidates": float((differ & ~same_cand).mean()),
            "float top-2 margin below one weight step": float((margin < step).mean()),
        }
    plain = {}
    for bits in (8, 9, 10, 11, 12):
        levels = (1 << bits) - 1
        scale = weights.max(axis=0) / levels
        scale = np.where(scale > 0, scale, 1.0)
        rounded = np.clip(np.floor(weights / scale + 0.5), 0, levels) * scale
        plain[bits] = float((run(inputs @ rounded, theta, lambda v: beta * v)[0] == reference).mean())
    out["b-bit weights, float dynamics"] = plain
    rng = np.random.default_rng(0)  # uniform noise of one and of a quarter 8-bit weight step instead of rounding
    step8 = np.where(weights.max(axis=0) > 0, weights.max(axis=0) / 255, 1.0)
    out["8-bit step noise, float dynamics"] = {
        f"U(-{f} s/2, {f} s/2)": float(
            (
                run(inputs @ (weights + f * (rng.random(weights.shape) - 0.5) * step8), theta, lambda v: beta * v)[0]
                == reference
            ).mean()
        )
        for f in (1.0, 0.25)
    }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
