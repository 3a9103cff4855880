"""Deployment: a float checkpoint becomes a calibrated fixed-point model.

Quantisation (:mod:`vprsnn_export.export.quantize`) maps weights and thresholds to integers; by default the
calibration S^R is then re-measured on the integer simulator, the network that will run.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import numpy as np
import torch

from vprsnn_export.arguments import require_type
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.export.quantize import DEFAULT_QUANTISE, QuantiseOptions, quantize_checkpoint
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.targets.intsim import IntegerNetwork
from vprsnn_export.trainer.calibrate import calibrate


def recalibrate(
    model: FixedPointModel,
    reference_images: Mapping[str, np.ndarray],
    place_ids: np.ndarray,
    *,
    reuse_float_calibration: bool = False,
    device: torch.device | None = None,
    progress: bool = False,
) -> FixedPointModel:
    """S^R of the deployed network: the reference presentations run on the integer simulator.

    With ``reuse_float_calibration`` the float S^R is kept instead (no simulation).
    The saturation events counted during calibration go into the quantisation report.
    """
    require_type("model", model, FixedPointModel)
    if reuse_float_calibration:
        calibration, how, saturations = model.float_calibration.copy(), "float (reused)", None
    else:
        check_reference_places(place_ids, model.reference_place_ids)
        if missing := [name for name in model.reference_traversals if name not in reference_images]:
            raise InvalidValueError(f"calibration needs the reference traversal(s) {', '.join(missing)}")
        network = IntegerNetwork(model, device=device, progress=progress)
        images = {name: reference_images[name] for name in model.reference_traversals}
        calibration = calibrate(network.counts, images, model.reference_place_ids, model.config)
        how, saturations = "deployed (integer simulator)", network.saturations
    report = dataclasses.replace(model.quantisation, calibration=how, calibration_saturations=saturations)
    return dataclasses.replace(model, calibration=calibration, quantisation=report)


def check_reference_places(place_ids: np.ndarray, reference_place_ids: np.ndarray) -> None:
    """InvalidValueError unless ``place_ids`` are the reference places, in their order: what calibration runs on."""
    if not np.array_equal(np.asarray(place_ids), reference_place_ids):
        raise InvalidValueError("calibration needs the checkpoint's reference places, in the same order")


def check_reference_images(options: QuantiseOptions, reference_images: Mapping[str, np.ndarray] | None) -> None:
    """InvalidValueError when the deployed calibration (re-measured on the integer simulator) has no reference images."""
    if options.calibration == "deployed" and reference_images is None:
        raise InvalidValueError("the deployed calibration needs the reference images")


def deploy(
    ckpt: Checkpoint,
    ckpt_sha256: str,
    bits: int,
    options: QuantiseOptions = DEFAULT_QUANTISE,
    *,
    reference_images: Mapping[str, np.ndarray] | None = None,
    device: torch.device | None = None,
    progress: bool = False,
) -> FixedPointModel:
    """Quantise ``ckpt`` to ``bits`` as ``options`` say and calibrate it: the model that `quantize` writes and
    `verify` checks.

    The deployed calibration (the default) re-measures S^R on the integer simulator and needs the checkpoint's
    reference images; a non-leaky deployment quantises the checkpoint with network.beta = 1 (decay_dv = 0).
    """
    require_type("ckpt", ckpt, Checkpoint)
    require_type("options", options, QuantiseOptions)  # the bit width: quantize_checkpoint's
    require_type("reference_images", reference_images, (Mapping, type(None)))
    check_reference_images(options, reference_images)
    model = quantize_checkpoint(ckpt, ckpt_sha256, bits, options)
    return recalibrate(
        model,
        dict(reference_images or {}),
        ckpt.reference_place_ids,
        reuse_float_calibration=options.calibration == "float",
        device=device,
        progress=progress,
    )
