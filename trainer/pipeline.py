"""Train on the reference traversals, then calibrate: the whole `vprsnn-export train` job."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from vprsnn_export.checkpoint import Checkpoint
from vprsnn_export.config import Config
from vprsnn_export.dataset import Dataset
from vprsnn_export.dynamics import FloatNetwork

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
    images = np.concatenate([dataset.traversal(name) for name in references])
    presentations = [Presentation(name, int(pid)) for name in references for pid in dataset.place_ids]
    trained = train_network(images, presentations, cfg, device=device, progress=progress)
    network = FloatNetwork.from_arrays(trained.weights.numpy(), trained.thresholds.numpy(), cfg, device)
    calibration = calibrate(
        network.counts, {name: dataset.traversal(name) for name in references}, dataset.place_ids, cfg
    )
    return Checkpoint(
        config=cfg,
        weights=trained.weights.numpy(),
        thresholds=trained.thresholds.numpy(),
        calibration=calibration,
        reference_place_ids=np.asarray(dataset.place_ids, dtype=np.int64),
        reference_traversals=list(references),
        data={"source": dataset.source, "manifest_sha256": dataset.manifest_sha256, **(selection or {})},
        history=trained.history,
    )
