"""Train on the reference traversals, then calibrate: the whole `vprsnn-export train` job."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from vprsnn_export.checkpoint import Checkpoint
from vprsnn_export.config import Config
from vprsnn_export.dataset import Dataset
from vprsnn_export.dynamics import FloatNetwork
from vprsnn_export.modules import module_regions

from .calibrate import calibrate
from .train import Presentation, train_network


def train_and_calibrate(
    dataset: Dataset,
    references: Sequence[str],
    cfg: Config,
    *,
    device: torch.device | None = None,
    progress: bool = True,
    selection: dict | None = None,
) -> Checkpoint:
    """Train on every image of the reference traversals, calibrate S^R, return the checkpoint (CPU by default)."""
    device = torch.device("cpu") if device is None else device
    weights, thresholds, history = [], [], []
    for start, stop in module_regions(len(dataset.place_ids), cfg.train.module_size):
        images = np.concatenate([dataset.traversal(name)[start:stop] for name in references])
        presentations = [Presentation(name, int(pid)) for name in references for pid in dataset.place_ids[start:stop]]
        trained = train_network(images, presentations, cfg, device=device, progress=progress)
        weights.append(trained.weights.numpy())
        thresholds.append(trained.thresholds.numpy())
        history = history or trained.history
    network = FloatNetwork.from_arrays(np.concatenate(weights, axis=1), np.concatenate(thresholds), cfg, device)
    calibration = calibrate(
        network.counts, {name: dataset.traversal(name) for name in references}, dataset.place_ids, cfg
    )
    return Checkpoint(
        config=cfg,
        weights=network.weights.cpu().numpy(),
        thresholds=network.thresholds.cpu().numpy(),
        calibration=calibration,
        reference_place_ids=np.asarray(dataset.place_ids, dtype=np.int64),
        reference_traversals=list(references),
        data={"source": dataset.source, "manifest_sha256": dataset.manifest_sha256, **(selection or {})},
        history=history,
    )
