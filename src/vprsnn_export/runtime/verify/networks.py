"""The networks and data of a `verify` run: the query data set with the reference images each network's
deployed calibration needs, and the seeds `verify --seeds N` trains from a template checkpoint."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from functools import partial
from pathlib import Path

import numpy as np

from vprsnn_export.data.dataset import Dataset, load_dataset
from vprsnn_export.device import resolve_device
from vprsnn_export.errors import DataError
from vprsnn_export.io.checkpoint import Checkpoint, save_checkpoint
from vprsnn_export.trainer.pipeline import train_and_calibrate


def verify_data(
    ckpt: Checkpoint, query: str, source: str, subset: str | None, places: str | None, progress: bool, cache: dict
) -> tuple[Dataset, dict[str, np.ndarray]]:
    """The query data set and the reference images of the checkpoint's reference places (for calibration)."""
    traversals = list(dict.fromkeys([*ckpt.reference_traversals, query]))
    key = (source, subset, places, tuple(traversals))
    load = partial(load_dataset, source, subset=subset, places=places, progress=progress)
    if key not in cache:
        try:
            cache[key] = load(traversals, ckpt.config.preprocess)
        except DataError:  # a folder whose query traversal has another length than the references': alone
            cache[key] = load([query], ckpt.config.preprocess)
    dataset = reference = cache[key]
    if not np.array_equal(dataset.place_ids, ckpt.reference_place_ids):  # load the reference places on their own
        reference = load(
            ckpt.reference_traversals, ckpt.config.preprocess, subset=ckpt.reference_place_ids, places=None
        )
    return dataset, {name: reference.traversal(name) for name in ckpt.reference_traversals}


def seed_networks(
    template: Checkpoint,
    n_seeds: int,
    dataset: Dataset,
    source: str,
    subset: str | None,
    places: str | None,
    out: Path,
    device_name: str,
    progress: bool,
) -> Iterator[tuple[str, Checkpoint, Path]]:
    """Seeds 1..N trained with the template's config on its reference traversals, one at a time, each
    written to DIR/checkpoints/seedN.npz (training is deterministic: the experiments' networks of that
    config, data and seed are the same bytes)."""
    for seed in range(1, n_seeds + 1):
        cfg = template.config.replace(seed=seed)
        ckpt = train_and_calibrate(
            dataset, template.reference_traversals, cfg, device=resolve_device(device_name), progress=progress
        )
        ckpt = dataclasses.replace(ckpt, data={**ckpt.data, "source": source, "subset": subset, "places": places})
        path = save_checkpoint(out / "checkpoints" / f"seed{seed}.npz", ckpt)
        yield f"seed {seed}", ckpt, path
