"""Train on the reference traversals, then calibrate: the whole `vprsnn-export train` job."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from vprsnn_export.arguments import require_bool, require_names, require_type
from vprsnn_export.cluster import Cluster
from vprsnn_export.config import Config
from vprsnn_export.data.dataset import Dataset
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.resources import LOWER_RUN, check_memory

from .batched import check_training_memory, module_training_rows, train_modules
from .calibrate import calibrate, calibration_need
from .sharded import calibrate_on_cluster, train_modules_on_cluster
from .train import Presentation


def train_and_calibrate(
    dataset: Dataset,
    references: Sequence[str],
    cfg: Config,
    *,
    device: torch.device | None = None,
    progress: bool = True,
    selection: dict | None = None,
    threads: int | None = None,
    cluster: Cluster | None = None,
    adaptation: str | None = None,
) -> Checkpoint:
    """Train on every image of the reference traversals, calibrate S^R, return the checkpoint (CPU by default).

    With ``train.module_size`` = P the places are cut into regions of P and one module per region
    is trained, all side by side (:func:`.batched.train_modules`); calibration presents every
    reference place to the whole ensemble (the hard WTA within config.wta_group). ``threads``: CPU
    threads for training and calibration (default: torch's thread count). ``cluster``: one task
    per module on that cluster (:mod:`.sharded`), the same checkpoint bit for bit; CPU workers.
    ``adaptation``: what :func:`.adaptation.adapt_config` learnt into ``cfg``, in one line (kept in ``data``).
    """
    require_type("dataset", dataset, Dataset)
    require_type("cfg", cfg, Config)
    progress = require_bool("progress", progress)
    if any(name not in dataset.images for name in require_names("references", references)):
        raise InvalidValueError(
            f"references must name traversals of the data set ({', '.join(dataset.images)}), got {references!r}"
        )
    device = torch.device("cpu") if device is None else device
    images = np.concatenate([dataset.traversal(name) for name in references])
    presentations = [Presentation(name, int(pid)) for name in references for pid in dataset.place_ids]
    rows = module_training_rows(len(dataset.place_ids), cfg.train.module_size, len(references))
    check_training_memory(cfg, len(rows), max(len(r) for r in rows), threads)
    n_places = len(dataset.place_ids)
    check_memory(calibration_need(cfg, n_places, len(rows) * cfg.network.n_neurons, n_places), "calibration", LOWER_RUN)
    reference_images = {name: dataset.traversal(name) for name in references}
    if cluster is not None:
        trained = train_modules_on_cluster(images, presentations, rows, cfg, cluster, progress=progress)
        arrays = (trained.weights.numpy(), trained.thresholds.numpy())
        calibration = calibrate_on_cluster(
            *arrays, cfg, reference_images, dataset.place_ids, cluster, progress=progress
        )
    else:
        trained = train_modules(images, presentations, rows, cfg, device=device, progress=progress, threads=threads)
        network = FloatNetwork.from_arrays(trained.weights.numpy(), trained.thresholds.numpy(), cfg, device)
        calibration = calibrate(network.counts, reference_images, dataset.place_ids, cfg, progress=progress)
    return Checkpoint(
        config=cfg,
        weights=trained.weights.numpy(),  # float32 on the CPU (TrainedNetwork)
        thresholds=trained.thresholds.numpy(),
        calibration=calibration,
        reference_place_ids=np.asarray(dataset.place_ids, dtype=np.int64),
        reference_traversals=list(references),
        data={
            "source": dataset.source,
            "manifest_sha256": dataset.manifest_sha256,
            **(selection or {}),
            **({"adaptation": adaptation} if adaptation else {}),
        },
        history=trained.history,
    )
