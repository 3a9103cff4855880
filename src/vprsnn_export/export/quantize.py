"""Quantising a float checkpoint into the fixed-point model of :mod:`export.model`.

Every neuron j gets a scale s_j ~= m_j 2**e (m_j an unsigned 16-bit multiplier, e
one exponent for the network); the float weight w_ij becomes the unsigned mantissa

    q_ij = clip(floor(w_ij / s_j + 1/2), 0, 2**b - 1)            (round to nearest, ties up)

and the float threshold becomes theta_int_j = clip(floor(theta_j / s_j + 1/2), 1, 2**17 - 1).
Per-tensor quantisation uses one scale per module (per weight tensor: an ensemble of M
modules, src/vprsnn_export/network/modules.py, stores M tensors side by side, module m owning the
columns [m n, (m + 1) n)); per-neuron one per column.
The scale method picks the desired s_j from the float weights:

    max:  s_j = max_i w_ij / (2**b - 1)                           (no weight clips)
    mse:  s_j = alpha* max_i w_ij / (2**b - 1),  alpha* = argmin_alpha sum_i (w_ij - s q_ij)**2
          over the grid MSE_GRID (large weights may clip to 2**b - 1)

Threshold folding (per-neuron only) gives every neuron the same integer threshold
Theta by choosing s_j = theta_j / Theta, for hardware with one threshold per
population. One Theta serves the whole ensemble (every module's population then has
the same vth, and the NIR file's one LIF node has one threshold, which snnTorch and
SpikingJelly need); the scales stay per neuron. Everything is derived from the
checkpoint; nothing is tuned by hand.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import sparse

from vprsnn_export.arguments import require_bool, require_choice, require_type
from vprsnn_export.errors import InvalidValueError, ModelFileError
from vprsnn_export.io.checkpoint import Checkpoint

from .model import (
    MULTIPLIER_BITS,
    THRESHOLD_BITS,
    FixedPointModel,
    QuantisationReport,
    check_bits,
    check_header,
    decay_mantissa,
    validate,
)

SCALE_METHODS = ("max", "mse")
MSE_GRID = np.linspace(0.2, 1.0, 81)  # fractions of the max-abs scale searched by the `mse` method
FOLD_CANDIDATES = 96  # integer shared thresholds tried by `mse` folding
ROUNDING = "round to nearest, ties up: floor(x + 1/2), then clip to the width"


@dataclass(frozen=True)
class QuantisedArrays:
    """The integer arrays of one quantisation and how far they are from the float ones."""

    weight_mantissa: np.ndarray  # (inputs, neurons) int32
    scale_multiplier: np.ndarray  # (neurons,) int32
    scale_exponent: int
    threshold: np.ndarray  # (neurons,) int32
    report: dict[str, Any]


def levels(bits: int) -> int:
    """Largest unsigned mantissa: L = 2**bits - 1 (2 bits: 4 levels 0..3)."""
    return (1 << bits) - 1


def round_half_up(x: np.ndarray) -> np.ndarray:
    """floor(x + 1/2): the one rounding rule of the quantiser."""
    return np.floor(np.asarray(x, dtype=np.float64) + 0.5)


def quantise_mantissas(weights: np.ndarray, scales: np.ndarray, bits: int) -> np.ndarray:
    """q_ij = clip(floor(w_ij / s_j + 1/2), 0, 2**bits - 1); ``scales`` broadcasts over columns."""
    return np.clip(round_half_up(weights / scales), 0, levels(bits)).astype(np.int32)


def column_sse(weights: np.ndarray, scales: np.ndarray, bits: int) -> np.ndarray:
    """E_j = sum_i (w_ij - s_j q_ij)**2, the squared quantisation error of each column."""
    error = weights - scales * quantise_mantissas(weights, scales, bits)
    return np.sum(error * error, axis=0)


def max_abs_scales(weights: np.ndarray, bits: int) -> np.ndarray:
    """s_j = max_i w_ij / (2**bits - 1) per column (an all-zero column gives 0)."""
    return weights.max(axis=0) / levels(bits)


def mse_scales(weights: np.ndarray, bits: int) -> np.ndarray:
    """s_j = alpha_j max_i w_ij / L with alpha_j in MSE_GRID minimising E_j (first minimum on ties)."""
    top = max_abs_scales(weights, bits)
    safe = np.where(top > 0, top, 1.0)
    errors = np.stack([column_sse(weights, alpha * safe, bits) for alpha in MSE_GRID])
    return MSE_GRID[np.argmin(errors, axis=0)] * top


def desired_scales(
    weights: np.ndarray, bits: int, method: str, per_neuron: bool, group: int | None = None
) -> np.ndarray:
    """The float scale s_j of every neuron before it is split into m_j 2**e.

    Per-tensor: the method applied to each module's weights as one column (module m:
    columns [m n, (m + 1) n), n = ``group``; None: one module), broadcast to the
    module's neurons. A neuron whose weights are all zero never fires; it takes its
    module's per-tensor scale (a module of zeros the whole ensemble's, else 1) so
    that its threshold still has a representable mantissa.
    """
    choose = max_abs_scales if method == "max" else mse_scales
    n_inputs, n_neurons = weights.shape
    group = group or n_neurons
    whole = float(choose(weights.reshape(-1, 1), bits)[0])
    whole = whole if whole > 0 else 1.0
    per_module = weights.reshape(n_inputs, -1, group).transpose(0, 2, 1).reshape(n_inputs * group, -1)
    modules = choose(per_module, bits)
    module_scale = np.repeat(np.where(modules > 0, modules, whole), group)
    if not per_neuron:
        return module_scale
    scales = choose(weights, bits)
    return np.where(scales > 0, scales, module_scale)


def split_scales(scales: np.ndarray) -> tuple[np.ndarray, int]:
    """s_j ~= m_j 2**e, one exponent for all neurons:

        e = floor(log2 max_j s_j) - (MULTIPLIER_BITS - 1),   m_j = clip(floor(s_j 2**-e + 1/2), 1, 2**16 - 1)

    The largest multiplier lands in [2**15, 2**16 - 1], so every m_j keeps as many
    significant bits as the ratio max_k s_k / s_j allows.
    """
    exponent = int(np.floor(np.log2(scales.max()))) - (MULTIPLIER_BITS - 1)
    multipliers = np.clip(round_half_up(np.ldexp(scales, -exponent)), 1, (1 << MULTIPLIER_BITS) - 1)
    return multipliers.astype(np.int32), exponent


def integer_thresholds(thresholds: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """theta_int_j = clip(floor(theta_j / s_j + 1/2), 1, 2**17 - 1)."""
    return np.clip(round_half_up(thresholds / scales), 1, (1 << THRESHOLD_BITS) - 1).astype(np.int32)


def shared_threshold(
    weights: np.ndarray, thresholds: np.ndarray, bits: int, method: str, per_neuron_scales: np.ndarray
) -> int:
    """The one integer threshold Theta of threshold folding (s_j = theta_j / Theta).

    max: Theta = floor(min_j theta_j / s*_j), so s_j >= s*_j and no weight clips.
    mse: Theta among integers spread geometrically over [min_j, max_j] of theta_j / s*_j
         minimising the total squared weight error sum_j E_j.
    """
    natural = thresholds / per_neuron_scales
    top = (1 << THRESHOLD_BITS) - 1
    if method == "max":
        return int(np.clip(np.floor(natural.min()), 1, top))
    grid = np.geomspace(max(natural.min(), 1.0), max(natural.max(), 1.0), FOLD_CANDIDATES)
    candidates = np.unique(np.clip(round_half_up(grid), 1, top)).astype(np.int64)
    errors = [column_sse(weights, thresholds / theta, bits).sum() for theta in candidates]
    return int(candidates[int(np.argmin(errors))])


def quantise_arrays(
    weights: np.ndarray, thresholds: np.ndarray, bits: int, options: QuantiseOptions, group: int | None = None
) -> QuantisedArrays:
    """Float weights (inputs, neurons) and thresholds (neurons,) -> mantissas, scales, integer thresholds.

    ``group`` is the neurons per module of an ensemble (None: one module): per-tensor
    scales are per module, and the report adds each module's errors.
    """
    check_bits(bits)
    method, fold = options.scale_method, options.fold_thresholds
    weights = np.asarray(weights, dtype=np.float64)
    thresholds = np.asarray(thresholds, dtype=np.float64)
    if fold and np.any(thresholds <= 0):
        raise InvalidValueError("threshold folding needs positive float thresholds")
    group = group or weights.shape[1]  # None or 0: one module of all neurons
    if weights.shape[1] % group:
        raise InvalidValueError(f"{weights.shape[1]} neurons do not split into modules of {group}")
    scales = desired_scales(weights, bits, method, options.per_neuron, group)
    theta_shared = None
    if fold:
        theta_shared = shared_threshold(weights, thresholds, bits, method, scales)
        scales = thresholds / theta_shared
    multipliers, exponent = split_scales(scales)
    actual = np.ldexp(multipliers.astype(np.float64), exponent)
    mantissas = quantise_mantissas(weights, actual, bits)
    integer_theta = (
        np.full(thresholds.shape, theta_shared, dtype=np.int32) if fold else integer_thresholds(thresholds, actual)
    )
    report = error_report(weights, thresholds, mantissas, actual, integer_theta, bits, group)
    report.update(
        bits=bits,
        per_neuron=options.per_neuron,
        scale_method=method,
        threshold_folding=fold,
        shared_threshold=theta_shared,
        rounding=ROUNDING,
        scale_exponent=exponent,
        scale_multiplier_range=[int(multipliers.min()), int(multipliers.max())],
        threshold_range=[int(integer_theta.min()), int(integer_theta.max())],
    )
    return QuantisedArrays(mantissas, multipliers, exponent, integer_theta, report)


def error_report(
    weights: np.ndarray,
    thresholds: np.ndarray,
    mantissas: np.ndarray,
    scales: np.ndarray,
    theta_int: np.ndarray,
    bits: int,
    group: int,
) -> dict[str, Any]:
    """How far the fixed-point network is from the float one (all plain JSON numbers), in all and per module
    (lists of M; module m = columns [m n, (m + 1) n), n = ``group``).

    weight errors are w_ij - q_ij s_j; threshold errors (theta_int_j s_j - theta_j) / theta_j;
    max_current is max_j sum_i q_ij, the largest possible a_j (every input spiking);
    module_weight_relative_rmse_m = sqrt(mean_m (w - q s)**2) / sqrt(mean_m w**2);
    module_weights_clipped_m = #{w / s >= 2**bits - 1/2};  module_max_current_m = max_{j in m} sum_i q_ij
    """
    n_inputs = weights.shape[0]

    def by_module(array: np.ndarray) -> np.ndarray:
        return array.reshape(n_inputs, -1, group).transpose(1, 0, 2).reshape(array.shape[1] // group, -1)

    error = weights - mantissas * scales
    rms = float(np.sqrt(np.mean(weights * weights))) or 1.0
    ratio, theta_ratio = weights / scales, thresholds / scales
    module_error = by_module(error)
    power = np.sqrt(np.mean(by_module(weights) ** 2, axis=1))
    module_rmse = np.sqrt(np.mean(module_error * module_error, axis=1)) / np.where(power > 0, power, 1.0)
    sums = mantissas.astype(np.int64).sum(axis=0)
    return {
        "weight_max_abs_error": float(np.abs(error).max()),
        "weight_rmse": float(np.sqrt(np.mean(error * error))),
        "weight_relative_rmse": float(np.sqrt(np.mean(error * error)) / rms),
        "weights_clipped": int(np.sum(ratio >= levels(bits) + 0.5)),
        "threshold_max_relative_error": float(
            np.max(np.abs(theta_int * scales - thresholds) / np.maximum(np.abs(thresholds), 1e-12))
        ),
        "thresholds_clipped": int(np.sum((theta_ratio >= (1 << THRESHOLD_BITS) - 0.5) | (theta_ratio < 0.5))),
        "max_current": int(sums.max()),
        "module_weight_relative_rmse": [float(x) for x in module_rmse],
        "module_weights_clipped": [int(x) for x in np.sum(by_module(ratio) >= levels(bits) + 0.5, axis=1)],
        "module_max_current": [int(x) for x in sums.reshape(-1, group).max(axis=1)],
    }


CALIBRATIONS = ("deployed", "float")


@dataclass(frozen=True)
class QuantiseOptions:
    """How a float checkpoint is quantised and calibrated: the one options object of `quantize`, :func:`deploy`,
    `verify` and the demo (the bit width is not here: each job deploys one model per width it is given).

    ``per_neuron``: one weight scale per neuron, else one per module (``--per-tensor``); ``scale_method``: "max"
    (max-abs, no weight clips) or "mse" (minimum squared error, ``--scale``); ``fold_thresholds``: per-neuron
    scales chosen so that every neuron shares one integer threshold; ``calibration``: "deployed" (S^R re-measured
    on the integer simulator) or "float" (the float S^R kept, ``--reuse-float-calibration``); ``non_leaky``: the
    trained weights and thresholds deployed without the leak (network.beta = 1, decay_dv = 0: V <- V + a), the mode
    every float NIR consumer computes exactly (docs/targets.md section 1.4). Validated once, when built.
    """

    per_neuron: bool = True
    scale_method: str = "max"
    fold_thresholds: bool = False
    calibration: str = "deployed"
    non_leaky: bool = False

    def __post_init__(self) -> None:
        for name in ("per_neuron", "fold_thresholds", "non_leaky"):  # a numpy bool becomes a bool
            object.__setattr__(self, name, require_bool(name, getattr(self, name)))
        require_choice("scale_method (--scale)", self.scale_method, SCALE_METHODS)
        require_choice("calibration", self.calibration, CALIBRATIONS)
        if self.fold_thresholds and not self.per_neuron:
            raise InvalidValueError(
                "fold_thresholds (--fold-thresholds) needs per-neuron scales: per_neuron=True (drop --per-tensor)"
            )
        if self.non_leaky and self.calibration != "deployed":
            raise InvalidValueError(
                "non_leaky (--non-leaky) needs the deployed calibration: calibration='deployed' (drop "
                "--reuse-float-calibration); the float S^R was measured with the leak"
            )


#: quantize's defaults: per-neuron max-abs scales, no folding, the deployed calibration, the leak kept.
DEFAULT_QUANTISE = QuantiseOptions()


def quantize_checkpoint(ckpt: Checkpoint, ckpt_sha256: str, bits: int, options: QuantiseOptions) -> FixedPointModel:
    """The fixed-point model of a float checkpoint as ``options`` say (scales, folding, the leak), still carrying
    the float calibration: ``calibration`` is a copy of the float S^R until
    :func:`~vprsnn_export.runtime.deployment.recalibrate` replaces it. A non-leaky deployment quantises the
    checkpoint with network.beta = 1 (decay_dv = 0).
    """
    require_type("ckpt", ckpt, Checkpoint)
    require_type("ckpt_sha256", ckpt_sha256, str)
    require_type("options", options, QuantiseOptions)  # the bit width: quantise_arrays's
    if options.non_leaky:
        ckpt = dataclasses.replace(ckpt, config=ckpt.config.replace(**{"network.beta": 1.0}))
    arrays = quantise_arrays(ckpt.weights, ckpt.thresholds, bits, options, ckpt.config.network.n_neurons)
    report = QuantisationReport.from_dict(
        dict(arrays.report, calibration="float (not recalibrated)", calibration_saturations=None)
    )
    sr = ckpt.calibration.toarray() if isinstance(ckpt.calibration, sparse.csr_array) else ckpt.calibration  # dense
    model = FixedPointModel(
        bits=int(bits),
        weight_mantissa=arrays.weight_mantissa,
        scale_multiplier=arrays.scale_multiplier,
        scale_exponent=arrays.scale_exponent,
        threshold=arrays.threshold,
        decay_dv=decay_mantissa(ckpt.config.network.beta),
        config=ckpt.config,
        calibration=sr.astype(np.int64, order="C"),
        float_calibration=sr.astype(np.int64, order="C"),
        reference_place_ids=ckpt.reference_place_ids.astype(np.int64).copy(),
        reference_traversals=list(ckpt.reference_traversals),
        quantisation=report,
        source_sha256=ckpt_sha256,
        data=dict(ckpt.data),
    )
    try:  # the writer's and reader's checks, so that every model made here can be saved and read back
        validate(model, Path("quantize_checkpoint"))
        check_header(model.header(), Path("quantize_checkpoint"))
    except ModelFileError as exc:
        raise InvalidValueError(f"this checkpoint cannot be quantised to a valid model ({exc})") from None
    return model
