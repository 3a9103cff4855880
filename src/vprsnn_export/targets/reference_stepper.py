"""The slow oracle: the docstring of export/model.py executed literally, one neuron at a time.

Independent of the fast simulator on purpose: integer currents from numpy int64 sums
(no float BLAS, no shifted weights), Python ints per neuron, truncation toward zero
written out with sign and abs, saturation checked on both sides, the WTA as an explicit
maximum of a_j m_j over the candidates with the lowest index winning ties.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from vprsnn_export.config import wta_group
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.network.runs import SpikeRun


def trunc_div(x: int, d: int) -> int:
    """x / d rounded toward zero: sign(x) (|x| // d)."""
    return -(-x // d) if x < 0 else x // d


def reference_run(model: FixedPointModel, spikes: np.ndarray, *, state_isolation: bool | None = None) -> SpikeRun:
    isolation = model.config.network.state_isolation if state_isolation is None else state_isolation
    n, timesteps, _ = spikes.shape
    q = model.weight_mantissa.astype(np.int64)
    m = [int(x) for x in model.scale_multiplier]
    vth = [int(x) << model.voltage_shift for x in model.threshold]
    keep, limit, neurons = 4096 - model.decay_dv, model.voltage_limit, range(model.n_neurons)
    group = wta_group(model.config, model.n_neurons)  # the WTA group: the ensemble or one module
    raster = np.zeros((n, timesteps, model.n_neurons), dtype=bool)
    final = np.zeros((n, model.n_neurons), dtype=np.int64)
    n_candidates = np.zeros((n, timesteps), dtype=np.int64)
    saturations = 0
    v = [0] * model.n_neurons
    for p in range(n):
        if isolation:
            v = [0] * model.n_neurons
        for t in range(timesteps):
            a = [int(x) for x in q[spikes[p, t] != 0].sum(axis=0, dtype=np.int64)]  # zeros when no input spikes
            for j in neurons:
                v[j] = trunc_div(v[j] * keep, 4096) + (a[j] << model.voltage_shift)
                if v[j] > limit or v[j] < -limit:
                    saturations += 1
                    v[j] = limit if v[j] > 0 else -limit
            candidates = [j for j in neurons if v[j] > vth[j]]
            n_candidates[p, t] = len(candidates)
            if model.config.network.wta:
                for module in range(model.n_neurons // group):
                    rivals = [j for j in candidates if j // group == module]
                    if rivals:  # max keeps the first of equal scores: the lowest index
                        raster[p, t, max(rivals, key=lambda j: a[j] * m[j])] = True
            else:
                raster[p, t, candidates] = True
            for j in candidates:
                v[j] = 0
        final[p] = v
    return SpikeRun(
        counts=torch.from_numpy(raster.sum(axis=1, dtype=np.int64)),
        candidates_per_step=torch.from_numpy(n_candidates.astype(np.int32)),
        raster=torch.from_numpy(raster),
        final_voltage=torch.from_numpy(final),
        saturations=saturations,
    )


@dataclass
class ReferenceStepper:
    """The slow oracle as a :class:`~vprsnn_export.network.runs.Backend` (always records: it is one loop either way)."""

    model: FixedPointModel
    name: str = "reference stepper"

    def run(self, spikes: torch.Tensor, *, record: bool = False) -> SpikeRun:
        return reference_run(self.model, np.asarray(spikes))
