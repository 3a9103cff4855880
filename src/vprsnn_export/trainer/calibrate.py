"""Calibration: the reference spike-count matrix S^R (neurons x places) with plasticity off."""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np
import torch

from vprsnn_export.config import Config
from vprsnn_export.data.encoding import calibration_spikes

CountRunner = Callable[[torch.Tensor], torch.Tensor]
"""Any network implementation: spikes (N, T, inputs) uint8 -> output spike counts (N, neurons)."""


def calibrate(
    run_counts: CountRunner,
    reference_images: Mapping[str, np.ndarray],
    place_ids: np.ndarray,
    cfg: Config,
) -> np.ndarray:
    """S^R_il = sum over reference traversals r of the spikes of neuron i for place l in traversal r.

    ``run_counts`` is the network under calibration (float, integer simulator,
    ONNX...), so a quantised network is calibrated with its own responses.
    """
    total = np.zeros((0, 0), dtype=np.int64)
    for traversal, images in reference_images.items():
        counts = run_counts(calibration_spikes(images, place_ids, traversal, cfg)).cpu().numpy().astype(np.int64)
        total = counts.T if total.size == 0 else total + counts.T
    return total
