"""The float network of an experiment on its query traversal, read out with its config's options."""

from __future__ import annotations

from typing import Any

from vprsnn_export.config import Config
from vprsnn_export.data.dataset import Dataset
from vprsnn_export.device import resolve_device
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.evaluation import Evaluation, evaluate_float

from .common import Settings


def evaluate_query(
    settings: Settings, ckpt: Checkpoint, data: Dataset, cfg: Config, baselines: bool = False, **readout: Any
) -> Evaluation:
    """``evaluate_float`` of ``ckpt`` on ``settings.query`` over ``data``'s places, on the settings' device, with
    :class:`~vprsnn_export.readout.sequence.SequenceOptions` (``readout``: the other readout options); ``baselines``: with
    the rows of SAD and cosine nearest neighbour on the same images (strategies "sad", "cosine")."""
    return evaluate_float(
        ckpt,
        data.traversal(settings.query),
        data.place_ids,
        settings.query,
        SequenceOptions(**readout),
        device=resolve_device(settings.device),
        reference_images={settings.reference: data.traversal(settings.reference)} if baselines else None,
    )


__all__ = ["evaluate_query"]
