"""Unsupervised STDP training: batches of presentations, per-step STDP, per-batch homeostasis."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch
from tqdm.auto import tqdm

from vprsnn_export.config import Config
from vprsnn_export.data.encoding import encode, presentation_seed
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.network.dynamics import wta_step

from .homeostasis import homeostasis_update
from .stdp import apply_update, decay_trace, initial_weights, stdp_delta
from .stdp_kernel import stdp_window


@dataclass(frozen=True)
class Presentation:
    """Which image a training row is: its traversal and place id (the encoder's key)."""

    traversal: str
    place_id: int


@dataclass
class TrainedNetwork:
    weights: torch.Tensor  # (inputs, neurons) float32, CPU
    thresholds: torch.Tensor  # (neurons,) float32, CPU
    history: list[dict] = field(default_factory=list)  # one entry per epoch


def train_batch(
    weights: torch.Tensor, theta: torch.Tensor, spikes: torch.Tensor, cfg: Config, *, compiled: bool = True
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Present one batch (B, T, inputs) with plasticity on; state starts at zero for every row.

    Per step: the WTA step of :mod:`vprsnn_export.network.dynamics`, trace decay, STDP
    (summed over the batch), clip and column normalisation. After the window:
    homeostasis with rbar_j = (spikes of j in the batch) / (B T).
    Returns (weights, thresholds, per-neuron spike counts of the batch).

    With a leading module dimension (spikes (M, B, T, inputs), weights (M, inputs, neurons),
    theta (M, neurons)) the torch loop trains M independent networks side by side, one
    batched matmul per step for all of them (:mod:`vprsnn_export.trainer.batched`).

    On the CPU the compiled kernel (:func:`vprsnn_export.trainer.stdp_kernel.stdp_window`) runs a single
    network's window when it can reproduce torch's summation order here (identical weights);
    otherwise, or with ``compiled=False``, the torch loop below.
    """
    *_, batch, timesteps, n_inputs = spikes.shape
    window = stdp_window(weights, theta, spikes, cfg) if compiled and spikes.dim() == 3 else None
    if window is not None:
        weights, fired_total = window
        return weights, homeostasis_update(theta, fired_total / (batch * timesteps), cfg.homeostasis), fired_total
    lead = tuple(spikes.shape[:-2])
    voltage = torch.zeros((*lead, weights.shape[-1]), dtype=weights.dtype, device=weights.device)
    post_trace = torch.zeros_like(voltage)
    pre_trace = torch.zeros((*lead, n_inputs), dtype=weights.dtype, device=weights.device)
    fired_total = torch.zeros((*lead[:-1], weights.shape[-1]), dtype=weights.dtype, device=weights.device)
    row_theta = theta.unsqueeze(-2)
    for t in range(timesteps):
        pre = spikes[..., t, :].to(weights.dtype)
        voltage, fired, _ = wta_step(voltage, pre @ weights, row_theta, cfg.network.beta, cfg.network.wta)
        post = fired.to(weights.dtype)
        pre_trace = decay_trace(pre_trace, pre, cfg.stdp.tau_pre)
        post_trace = decay_trace(post_trace, post, cfg.stdp.tau_post)
        weights = apply_update(weights, stdp_delta(weights, pre_trace, pre, post_trace, post, cfg.stdp), cfg.stdp)
        fired_total += post.sum(dim=-2)
    return weights, homeostasis_update(theta, fired_total / (batch * timesteps), cfg.homeostasis), fired_total


def training_seeds(cfg: Config, presentations: Sequence[Presentation], rows: np.ndarray, epoch: int) -> list[int]:
    """The encoder key of each training row in one epoch: presentation_seed(seed, "train", traversal, place, epoch)."""
    return [
        presentation_seed(cfg.seed, "train", presentations[r].traversal, presentations[r].place_id, epoch) for r in rows
    ]


def epoch_order(seed: int, epoch: int, n_rows: int) -> torch.Tensor:
    generator = torch.Generator().manual_seed(presentation_seed(seed, "shuffle", "", 0, epoch))
    return torch.randperm(n_rows, generator=generator)


def initial_state(cfg: Config, n_modules: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """Every module starts from initial_weights(seed) (M, inputs, n) and theta_init (M, n)."""
    generator = torch.Generator().manual_seed(presentation_seed(cfg.seed, "init", "", 0))
    start = initial_weights(cfg.network.n_inputs, cfg.network.n_neurons, generator)
    weights = start.unsqueeze(0).repeat(n_modules, 1, 1).contiguous().to(device)
    theta = torch.full((n_modules, cfg.network.n_neurons), cfg.network.theta_init, dtype=torch.float32, device=device)
    return weights, theta


def train_network(
    images: np.ndarray,
    presentations: Sequence[Presentation],
    cfg: Config,
    *,
    device: torch.device,
    progress: bool = True,
    on_epoch: Callable[[int, torch.Tensor, torch.Tensor], dict | None] | None = None,
    compiled: bool = True,
) -> TrainedNetwork:
    """Train from the preprocessed reference images (rows aligned with ``presentations``).

    Everything random derives from ``cfg.seed``: initial weights, the shuffle of
    each epoch and every spike. ``on_epoch(epoch, weights, theta)`` may return
    extra numbers to store in the history (used by the epoch-curve experiment).
    ``compiled=False`` runs every batch through the torch loop (see :func:`train_batch`).
    """
    if len(images) == 0:
        raise InvalidValueError("no training images")
    weights, theta = (state[0] for state in initial_state(cfg, 1, device))
    history: list[dict] = []
    epochs = tqdm(range(cfg.train.epochs), desc="train", unit="epoch", disable=not progress, leave=False)
    for epoch in epochs:
        started = time.perf_counter()
        order = epoch_order(cfg.seed, epoch, len(images)).numpy()
        fired = torch.zeros(cfg.network.n_neurons, dtype=torch.float32, device=device)
        for start in range(0, len(order), cfg.train.batch_size):
            rows = order[start : start + cfg.train.batch_size]
            seeds = training_seeds(cfg, presentations, rows, epoch)
            spikes = encode(images[rows], seeds, cfg.training_encoder).to(device)
            weights, theta, batch_fired = train_batch(weights, theta, spikes, cfg, compiled=compiled)
            fired += batch_fired
        entry = history_entry(epoch, time.perf_counter() - started, fired, theta, np.array([len(images)]))
        if on_epoch is not None:
            entry.update(on_epoch(epoch + 1, weights, theta) or {})
        history.append(entry)
        epochs.set_postfix(active=entry["active_neurons"], theta=f"{entry['theta_mean']:.3f}")
    return TrainedNetwork(weights.cpu(), theta.cpu(), history)


def history_entry(epoch: int, seconds: float, fired: torch.Tensor, theta: torch.Tensor, n_rows: np.ndarray) -> dict:
    """One epoch over all modules; with M > 1 also each module's spikes per presentation and active neurons."""
    counts = fired.cpu().to(torch.float64)
    entry: dict = {
        "epoch": epoch + 1,
        "seconds": seconds,
        "spikes_per_presentation": float(counts.sum()) / int(n_rows.sum()),
        "active_neurons": int((counts > 0).sum()),
        "theta_mean": float(theta.reshape(-1).mean()),
    }
    if len(n_rows) > 1:
        entry["module_spikes_per_presentation"] = [
            round(float(c) / int(r), 4) for c, r in zip(counts.sum(dim=1), n_rows, strict=True)
        ]
        entry["module_active_neurons"] = [int(a) for a in (counts > 0).sum(dim=1)]
    return entry
