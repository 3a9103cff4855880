"""Modules trained side by side: M independent networks as one batched computation.

An ensemble (:mod:`vprsnn_export.network.modules`) has one network per region of consecutive places.
Module m trains on its own rows only (its region's places in every reference traversal), with
everything random derived from the run's one seed exactly as :func:`.train.train_network` derives
it for that region alone:

    W_m[0]      = initial_weights(seed)                      (the same for every module)
    order_m[e]  = epoch_order(seed, e, rows_m)               (its own row count)
    batch k     = rows order_m[e][k B : (k + 1) B]           (modules with fewer rows have fewer batches)
    spikes      = encode(images, presentation_seed(seed, "train", traversal, place, e))

so module m's weights and thresholds are bit for bit those of ``train_network`` on its region
with the same seed. A module without a batch k sits it out (no update, no homeostasis).

The weights are held as (M, inputs, n). On the CPU the compiled kernel
(:func:`vprsnn_export.trainer.stdp_kernel.stdp_windows`) runs every module's batch in one call, in
contiguous slices of modules on ``threads`` Python threads; elsewhere (a GPU, ``compiled=False``
or a BLAS whose order the kernel cannot reproduce) the torch loop of :func:`.train.train_batch`
runs all modules with the same batch size at once, one batched matmul per step.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from tqdm.auto import tqdm

from vprsnn_export.config import Config
from vprsnn_export.data.encoding import encode, firing_probabilities
from vprsnn_export.data.encoding_kernel import bernoulli_limits, generator_seeds
from vprsnn_export.data.philox import philox_spikes
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.network.modules import module_regions
from vprsnn_export.resources import LOWER_TRAINING, check_memory, training_need

from .homeostasis import homeostasis_update
from .stdp_kernel import stdp_windows
from .train import Presentation, TrainedNetwork, epoch_order, history_entry, initial_state, train_batch, training_seeds


def module_training_rows(n_places: int, module_size: int, n_traversals: int) -> list[np.ndarray]:
    """Module m's training rows: r N + [start_m, stop_m) for each reference traversal r in order.

    Rows index the reference images stacked traversal after traversal (N places each), the
    order in which ``train_network`` sees one region's images.
    """
    return [
        np.concatenate([np.arange(start, stop, dtype=np.int64) + r * n_places for r in range(n_traversals)])
        for start, stop in module_regions(n_places, module_size)
    ]


def _kernel_batch(
    weights: torch.Tensor,
    theta: torch.Tensor,
    images: np.ndarray,
    presentations: Sequence[Presentation],
    batch_rows: Sequence[np.ndarray],
    cfg: Config,
    epoch: int,
    threads: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Every module's batch through the compiled kernel (weights updated in place), then its homeostasis:
    theta_m <- homeostasis_update(theta_m, fired_m / (B_m T)) for every module with a batch (B_m > 0)."""
    sizes = np.array([len(rows) for rows in batch_rows], dtype=np.int64)
    limits = np.zeros((len(batch_rows), int(sizes.max()), images.shape[1]), dtype=np.int32)
    seeds = np.zeros(limits.shape[:2], dtype=np.int64)
    for m, rows in enumerate(batch_rows):
        if len(rows):
            limits[m, : len(rows)] = bernoulli_limits(firing_probabilities(images[rows], cfg.training_encoder).numpy())
            seeds[m, : len(rows)] = generator_seeds(
                training_seeds(cfg, presentations, rows, epoch), cfg.encoder.generator
            )
    fired = torch.from_numpy(stdp_windows(weights.numpy(), theta.numpy(), limits, seeds, sizes, cfg, threads=threads))
    theta = theta.clone()
    for size in sorted({int(s) for s in sizes if s > 0}):
        index = torch.from_numpy(np.flatnonzero(sizes == size)).to(theta.device)
        rate = fired[index] / (size * cfg.training_encoder.timesteps)
        theta[index] = homeostasis_update(theta[index], rate, cfg.homeostasis)
    return weights, theta, fired


def _torch_batch(
    weights: torch.Tensor,
    theta: torch.Tensor,
    images: np.ndarray,
    presentations: Sequence[Presentation],
    batch_rows: Sequence[np.ndarray],
    cfg: Config,
    epoch: int,
    threads: int,  # the kernel's (this loop runs on torch's threads)
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The torch loop for all modules with the same batch size at once (one batched matmul per step)."""
    sizes = np.array([len(rows) for rows in batch_rows], dtype=np.int64)
    weights, theta = weights.clone(), theta.clone()
    fired = torch.zeros_like(theta)
    for size in sorted({int(s) for s in sizes if s > 0}):
        members = np.flatnonzero(sizes == size)
        rows = np.concatenate([batch_rows[int(m)] for m in members])  # every member's batch, drawn at once
        spikes = device_spikes(images[rows], training_seeds(cfg, presentations, rows, epoch), cfg, weights.device)
        spikes = spikes.reshape(len(members), size, *spikes.shape[1:])
        index = torch.from_numpy(members).to(weights.device)
        weights[index], theta[index], fired[index] = train_batch(
            weights[index], theta[index], spikes, cfg, compiled=False
        )
    return weights, theta, fired


def device_spikes(images: np.ndarray, seeds: Sequence[int], cfg: Config, device: torch.device) -> torch.Tensor:
    """A training batch's spikes on ``device``: with the Philox generator drawn there (:func:`.philox_spikes`, the
    CPU encoder's bits), else encoded on the CPU and copied."""
    encoder = cfg.training_encoder
    if encoder.generator != "philox" or device.type == "cpu":
        return encode(images, seeds, encoder).to(device)
    limits = torch.from_numpy(bernoulli_limits(firing_probabilities(images, encoder).numpy())).to(device)
    return philox_spikes(limits, torch.from_numpy(generator_seeds(seeds, "philox")), encoder.timesteps)


@dataclass(frozen=True)
class EpochState:
    """Where training stands after one epoch: what fired and the thresholds, per module (M, n).

    ``weights`` (M, inputs, n) is the live training tensor: read it before the next epoch runs.
    """

    epoch: int  # 0-based
    seconds: float
    fired: torch.Tensor  # (M, n) float32 spikes of each neuron over the epoch
    theta: torch.Tensor  # (M, n) float32 thresholds after the epoch
    weights: torch.Tensor  # (M, inputs, n)


def module_epochs(
    images: np.ndarray,
    presentations: Sequence[Presentation],
    rows: Sequence[np.ndarray],
    cfg: Config,
    *,
    device: torch.device,
    threads: int | None = None,
    compiled: bool = True,
) -> Iterator[EpochState]:
    """Train M modules side by side (module m on ``images[rows[m]]``), yielding the state after each epoch.

    Module m's trajectory depends on its rows and ``cfg`` alone (see the module docstring), so
    any subset of modules trained here, in this process or on a worker, follows it bit for bit.
    """
    if not rows or any(len(r) == 0 for r in rows):
        raise InvalidValueError("no training images for a module")
    n_modules, n_neurons, batch = len(rows), cfg.network.n_neurons, cfg.train.batch_size
    threads = torch.get_num_threads() if threads is None else max(1, int(threads))
    weights, theta = initial_state(cfg, n_modules, device)
    step = _kernel_batch if compiled and device.type == "cpu" else _torch_batch
    n_rows = np.array([len(r) for r in rows])
    for epoch in range(cfg.train.epochs):
        started = time.perf_counter()
        orders = {int(count): epoch_order(cfg.seed, epoch, int(count)).numpy() for count in set(n_rows)}
        fired = torch.zeros((n_modules, n_neurons), dtype=torch.float32, device=device)
        for first in range(0, int(n_rows.max()), batch):
            batch_rows = [r[orders[len(r)][first : first + batch]] for r in rows]
            weights, theta, batch_fired = step(weights, theta, images, presentations, batch_rows, cfg, epoch, threads)
            fired += batch_fired
        yield EpochState(epoch, time.perf_counter() - started, fired, theta, weights)


def check_training_memory(cfg: Config, n_modules: int, most_rows: int, threads: int | None) -> None:
    """InvalidValueError (one line) when training ``n_modules`` modules would not fit in the memory limit."""
    workers = max(1, min(n_modules, torch.get_num_threads() if threads is None else threads))
    need = training_need(
        n_modules=n_modules,
        n_inputs=cfg.network.n_inputs,
        n_neurons=cfg.network.n_neurons,
        timesteps=cfg.training_encoder.timesteps,
        batch=max(1, min(cfg.train.batch_size, most_rows)),
        threads=workers,
    )
    check_memory(need, "training", LOWER_TRAINING)


def train_modules(
    images: np.ndarray,
    presentations: Sequence[Presentation],
    rows: Sequence[np.ndarray],
    cfg: Config,
    *,
    device: torch.device,
    progress: bool = True,
    threads: int | None = None,
    compiled: bool = True,
    on_epoch: Callable[[int, torch.Tensor, torch.Tensor], dict | None] | None = None,
) -> TrainedNetwork:
    """Train M modules side by side; module m on ``images[rows[m]]`` (rows aligned with ``presentations``).

    Returns one network of M n neurons side by side, module m's neurons [m n, (m + 1) n): weights
    (inputs, M n) and thresholds (M n,), each module's bit for bit ``train_network`` on its rows
    with ``cfg.seed``. ``threads``: Python threads for the compiled kernel (default: torch's thread
    count, i.e. ``--threads``). History: one entry per epoch over all modules (spikes per
    presentation, active neurons, mean threshold), with per-module lists when M > 1.
    ``on_epoch(epoch, weights (inputs, M n), theta (M n,))`` may add numbers to the entry.
    """
    n_rows = np.array([len(r) for r in rows])
    check_training_memory(cfg, len(rows), int(n_rows.max(initial=0)), threads)
    states = module_epochs(images, presentations, rows, cfg, device=device, threads=threads, compiled=compiled)
    desc = "train" if len(rows) == 1 else f"train {len(rows)} modules"  # the bar's ETA: the time left
    epochs = tqdm(states, total=cfg.train.epochs, desc=desc, unit="epoch", disable=not progress, leave=False)
    history: list[dict] = []
    weights, theta = initial_state(cfg, len(rows), device)
    for state in epochs:
        weights, theta = state.weights, state.theta
        entry = history_entry(state.epoch, state.seconds, state.fired, theta, n_rows)
        if on_epoch is not None:
            entry.update(on_epoch(state.epoch + 1, side_by_side(weights), theta.reshape(-1)) or {})
        history.append(entry)
        epochs.set_postfix(active=entry["active_neurons"], theta=f"{entry['theta_mean']:.3f}")
    return TrainedNetwork(side_by_side(weights).cpu(), theta.reshape(-1).cpu(), history)


def side_by_side(weights: torch.Tensor) -> torch.Tensor:
    """(M, inputs, n) -> (inputs, M n): module m's columns [m n, (m + 1) n)."""
    n_modules, n_inputs, n_neurons = weights.shape
    return weights.permute(1, 0, 2).reshape(n_inputs, n_modules * n_neurons).contiguous()
