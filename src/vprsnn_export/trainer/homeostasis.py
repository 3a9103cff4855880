"""Global batch-level homeostasis of the thresholds (paper eq. 8)."""

from __future__ import annotations

import torch

from vprsnn_export.config import HomeostasisConfig


def homeostasis_update(theta: torch.Tensor, mean_rate: torch.Tensor, cfg: HomeostasisConfig) -> torch.Tensor:
    """theta_j <- clip(theta_j + eta (rbar_j - r_target), theta_min, theta_max).

    rbar_j is neuron j's spikes per step averaged over the batch and the whole
    window T. A neuron firing above r_target gets a higher threshold, one below
    it a lower one. The bounds are the paper's code's [0.6, 100].
    """
    if not cfg.enabled:
        return theta
    return torch.clamp(theta + cfg.eta * (mean_rate - cfg.r_target), cfg.theta_min, cfg.theta_max)
