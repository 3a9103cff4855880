"""Trace STDP with soft bounds and column L2 normalisation (paper eq. 5-7).

W has shape (inputs, neurons): column j holds neuron j's afferent weights.
"""

from __future__ import annotations

import torch

from vprsnn_export.config import STDPConfig


def decay_trace(trace: torch.Tensor, spikes: torch.Tensor, tau: float) -> torch.Tensor:
    """x[t] = x[t-1] (1 - 1/tau) + s[t]   (eq. 5 and 6)."""
    return trace * (1.0 - 1.0 / tau) + spikes


def stdp_delta(
    weights: torch.Tensor,
    pre_trace: torch.Tensor,
    pre_spikes: torch.Tensor,
    post_trace: torch.Tensor,
    post_spikes: torch.Tensor,
    cfg: STDPConfig,
) -> torch.Tensor:
    """dW = A+ (w_max - W) * (x^T S) - A- W * (s^T y), summed over the batch (eq. 7).

    pre_trace x and pre_spikes s are (B, inputs); post_trace y and post_spikes S are (B, neurons).
    With leading module dimensions (M, B, ...) and weights (M, inputs, neurons), one batched
    matmul computes every module's terms.
    """
    potentiation = pre_trace.transpose(-2, -1) @ post_spikes
    depression = pre_spikes.transpose(-2, -1) @ post_trace
    return cfg.a_plus * (cfg.w_max - weights) * potentiation - cfg.a_minus * weights * depression


def normalise_columns(weights: torch.Tensor) -> torch.Tensor:
    """w_ij <- w_ij / sqrt(sum_k w_kj^2); an all-zero column stays zero (any leading module dimensions)."""
    norms = torch.linalg.vector_norm(weights, dim=-2, keepdim=True)
    return weights / torch.clamp(norms, min=torch.finfo(weights.dtype).tiny)


def apply_update(weights: torch.Tensor, delta: torch.Tensor, cfg: STDPConfig) -> torch.Tensor:
    """W <- clip(W + dW, 0, w_max), then column L2 normalisation when ``cfg.weight_norm``."""
    weights = torch.clamp(weights + delta, 0.0, cfg.w_max)
    return normalise_columns(weights) if cfg.weight_norm else weights


def initial_weights(n_inputs: int, n_neurons: int, generator: torch.Generator) -> torch.Tensor:
    """W ~ U[0, 1) (inputs, neurons), each column then L2-normalised (the paper's code)."""
    return normalise_columns(torch.rand((n_inputs, n_neurons), generator=generator))
