"""Deployment: a float checkpoint becomes a calibrated fixed-point model.

Quantisation (:mod:`vprsnn_export.export.quantize`) maps weights and thresholds to
integers; the deployed network then answers the reference places differently from
the float one, so by default its calibration S^R is re-measured on the integer
simulator (the network that will run), exactly as the float network was calibrated.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import numpy as np
import torch

from vprsnn_export.arguments import require_type
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.export.quantize import quantize_checkpoint
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.targets.intsim import IntegerNetwork
from vprsnn_export.trainer.calibrate import calibrate

CALIBRATIONS = ("deployed", "float")


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
        report = dataclasses.replace(model.quantisation, calibration="float (reused)", calibration_saturations=None)
        return dataclasses.replace(model, calibration=model.float_calibration.copy(), quantisation=report)
    if not np.array_equal(np.asarray(place_ids), model.reference_place_ids):
        raise InvalidValueError("calibration needs the checkpoint's reference places, in the same order")
    missing = [name for name in model.reference_traversals if name not in reference_images]
    if missing:
        raise InvalidValueError(f"calibration needs the reference traversal(s) {', '.join(missing)}")
    network = IntegerNetwork(model, device=device, progress=progress)
    images = {name: reference_images[name] for name in model.reference_traversals}
    calibration = calibrate(network.counts, images, model.reference_place_ids, model.config)
    report = dataclasses.replace(
        model.quantisation, calibration="deployed (integer simulator)", calibration_saturations=network.saturations
    )
    return dataclasses.replace(model, calibration=calibration, quantisation=report)


def deploy(
    ckpt: Checkpoint,
    ckpt_sha256: str,
    bits: int,
    *,
    per_neuron: bool = True,
    scale_method: str = "max",
    fold_thresholds: bool = False,
    calibration: str = "deployed",
    reference_images: Mapping[str, np.ndarray] | None = None,
    device: torch.device | None = None,
    non_leaky: bool = False,
    progress: bool = False,
) -> FixedPointModel:
    """Quantise ``ckpt`` to ``bits`` and calibrate it: the model that `quantize` writes and `verify` checks.

    ``calibration="deployed"`` re-measures S^R on the integer simulator (needs the
    checkpoint's reference images); ``"float"`` keeps the float network's S^R.
    ``non_leaky`` deploys the trained weights and thresholds without the leak (network.beta = 1,
    decay_dv = 0: V <- V + a), the mode every float NIR consumer computes exactly
    (docs/targets.md section 1.4); it needs the deployed calibration, since S^R changes with the dynamics.
    """
    require_type("ckpt", ckpt, Checkpoint)
    require_type("reference_images", reference_images, (Mapping, type(None)))
    if not isinstance(calibration, str) or calibration not in CALIBRATIONS:
        raise InvalidValueError(f"calibration must be one of {', '.join(CALIBRATIONS)}, got {calibration!r}")
    if non_leaky and calibration != "deployed":
        raise InvalidValueError("a non-leaky deployment needs the deployed calibration (the float S^R has a leak)")
    if non_leaky:
        ckpt = dataclasses.replace(ckpt, config=ckpt.config.replace(**{"network.beta": 1.0}))
    if calibration == "deployed" and reference_images is None:
        raise InvalidValueError("the deployed calibration needs the reference images")
    model = quantize_checkpoint(
        ckpt, ckpt_sha256, bits, per_neuron=per_neuron, scale_method=scale_method, fold_thresholds=fold_thresholds
    )
    return recalibrate(
        model,
        dict(reference_images or {}),
        ckpt.reference_place_ids,
        reuse_float_calibration=calibration == "float",
        device=device,
        progress=progress,
    )
