"""Where the 8-bit network's spikes differ from the float network's (docs/fixed-point.md section 8).

The integer network differs from the float one by four roundings: the weight mantissas,
the threshold mantissas, the 12-bit decay (beta -> (4096 - dv) / 4096) and the decay's
truncation toward zero. These tests pin the measured split: at 8 bits the weight
mantissas alone account for the difference, the other three change almost no step.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vprsnn_export.config import preset
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.export.model import DECAY_BITS
from vprsnn_export.export.quantize import QuantiseOptions, quantize_checkpoint
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.targets.intsim import simulate, step_agreement

CPU = torch.device("cpu")


@pytest.fixture(scope="module")
def trained():
    from vprsnn_export.trainer.pipeline import train_and_calibrate

    cfg = preset("paper").replace(
        **{"network.n_neurons": 32, "encoder.timesteps": 60, "train.epochs": 3, "train.batch_size": 8}
    )
    data = load_dataset("synthetic:16", ["summer", "winter"], cfg.preprocess)
    ckpt = train_and_calibrate(data, ["summer"], cfg, device=CPU, progress=False)
    spikes = query_spikes(data.traversal("winter"), data.place_ids, "winter", cfg)
    float_raster = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, cfg, CPU).run(spikes, record=True).raster
    return ckpt, spikes, float_raster


def float_raster(weights: np.ndarray, thresholds: np.ndarray, cfg, spikes: torch.Tensor) -> torch.Tensor:
    """The float network's spikes (N, T, neurons) with the given weights and thresholds."""
    return FloatNetwork.from_arrays(weights, thresholds, cfg, CPU).run(spikes, record=True).raster


def test_at_eight_bits_only_the_weight_mantissas_move_spikes(trained):
    """The integer network = the float network on its dequantised weights q_ij s_j (float
    thresholds, float beta) on >= 99 % of steps: threshold rounding, the 12-bit decay and
    truncation toward zero together move < 1 % of the steps the weight rounding moves."""
    ckpt, spikes, reference = trained
    model = quantize_checkpoint(ckpt, "0" * 64, 8, QuantiseOptions())
    scale = np.ldexp(model.scale_multiplier.astype(np.float64), model.scale_exponent)
    dequantised = model.weight_mantissa * scale
    integer = simulate(model, spikes, record=True).raster
    weights_only = float_raster(dequantised, ckpt.thresholds, ckpt.config, spikes)
    with_all = float_raster(
        dequantised,
        model.threshold * scale,
        ckpt.config.replace(**{"network.beta": 1 - model.decay_dv / (1 << DECAY_BITS)}),
        spikes,
    )
    to_float = 1 - step_agreement(reference, integer)["all_steps"]
    assert to_float > 0  # the weight rounding does move spikes on this network
    assert step_agreement(weights_only, integer)["all_steps"] >= 0.99
    assert step_agreement(with_all, integer)["all_steps"] >= 0.995
    assert abs(step_agreement(reference, weights_only)["all_steps"] - (1 - to_float)) <= 0.01
