"""The fixed-point model: integer arrays plus a JSON header, the contract between every target.

Integer dynamics, per presentation, per step t (all integers; see docs/fixed-point.md):

    a_j[t] = sum_i q_ij s_i[t]                                   (weight mantissas q, unsigned, `bits` wide)
    V_j[t] = sat24( trunc0(V_j[t-1] (4096 - dv) / 4096) + (a_j[t] << voltage_shift) )
    C[t]   = { j : V_j[t] > theta_j << voltage_shift }
    WTA:     S_j[t] = 1 for the j in C[t] maximising a_j[t] m_j   (ties: lowest index),
             within each WTA group (config.wta_group: all M n neurons of an ensemble when
             network.wta_scope = ensemble, else each module's n = network.n_neurons)
    V_j[t] <- 0 for j in C[t]

trunc0 rounds toward zero (Lava's decay); sat24 clips to [-(2**23 - 1), 2**23 - 1] and
every clip is counted as a saturation event. The float weight the mantissa stands for
is w_ij ~= q_ij * m_j * 2**scale_exponent, and the float threshold theta_j ~=
theta_int_j * m_j * 2**scale_exponent, so each neuron's voltage lives in its own
scale and comparing currents across neurons (the WTA) uses a_j m_j.

Every implementation of the LIF + WTA step, and the test that proves it equal to the one it
is checked against (docs/fixed-point.md §5.1 has the same table):

    implementation                          where                                 proved equal by
    float step (torch; the reference)       dynamics.wta_step / run_network       tests/core/network/test_dynamics.py (by hand)
    float kernel loop (numba)               dynamics_kernel.float_run             tests/core/network/test_dynamics_kernel.py::test_float_kernel_matches_run_network
    training window (numba, WTA + STDP)     trainer/stdp_kernel.stdp_window / stdp_windows  tests/trainer/test_stdp_kernel.py::test_stdp_window_gives_train_batch_weights_bit_for_bit_where_no_sum_can_differ
    integer kernel loop (numba)             targets/intsim_kernel.integer_run     tests/targets/test_intsim_kernel.py::test_integer_kernel_is_bit_identical_to_the_simulator_and_the_reference
    integer simulator (torch path)          targets/intsim.run_prepared           tests/targets/test_intsim.py::test_fast_simulator_equals_reference_on_random_models,
                                                                                  tests/targets/test_device_paths.py::test_torch_integer_path_equals_the_cpu_kernel
    reference stepper (Python ints)         targets/reference_stepper.reference_run  this docstring executed literally (the oracle of the two above)
    ONNX graph (onnxruntime)                targets/onnx_target.step_body         tests/targets/test_onnx_target.py::test_property_onnx_equals_simulator
    NIR file read back + readout rule       targets/nir_target, nir_read          tests/targets/test_nir_target.py::test_fixed_point_round_trip_is_exact,
                                            (nir_semantics)                       ::test_readout_rule_on_the_wta_off_raster_gives_the_integer_network
    NIR consumer runners                    targets/nir_consumers.run_consumer    tests/targets/test_consumers.py::test_each_consumer_runs_a_single_threshold_fixed_point_file_exactly
    Loihi-style description (Lava, netx)    targets/loihi_target                  tests/targets/test_loihi_target.py::test_round_trip_rebuilds_the_model_exactly,
                                                                                  ::test_lava_runs_the_description_spike_for_spike, tests/targets/test_netx.py
                                                                                  (Lava and netx: run where a Python 3.10 Lava venv can be built, skipped otherwise)
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from vprsnn_export.arguments import require_path
from vprsnn_export.config import Config, wta_group
from vprsnn_export.errors import InvalidValueError, ModelFileError, VprError
from vprsnn_export.io.checkpoint import reference_header, validate_reference_ids
from vprsnn_export.io.fileio import read_container, write_container
from vprsnn_export.io.serial import json_options, to_json_dict
from vprsnn_export.network.modules import ensemble_neurons
from vprsnn_export.network.widths import DECAY_BITS
from vprsnn_export.version import __version__

FORMAT = "vprsnn-fixed-point"
FORMAT_VERSION = 1
SUPPORTED_BITS = (2, 3, 4, 5, 6, 7, 8)
VOLTAGE_BITS = 24  # Loihi: 24-bit signed membrane voltage
VOLTAGE_SHIFT = 6  # Loihi: the synaptic input and vth mantissa are shifted left by 6
MULTIPLIER_BITS = 16  # per-neuron scale multipliers m_j are unsigned 16-bit
DEFAULT_BITS = (8, 4, 2)  # the weight widths quantize, verify and demo use unless told otherwise
THRESHOLD_BITS = 17  # Loihi: vth mantissa is 17 bits unsigned
MIN_EXPONENT, MAX_EXPONENT = -64, 8  # the shared scale exponent e of s_j = m_j 2**e that a header may state


def decay_mantissa(beta: float) -> int:
    """dv = round(4096 (1 - beta)) (Loihi's 12-bit voltage decay)."""
    return int(round((1 << DECAY_BITS) * (1.0 - beta)))


def check_bits(bits: int) -> int:
    if isinstance(bits, bool) or not isinstance(bits, int | np.integer) or int(bits) not in SUPPORTED_BITS:
        raise InvalidValueError(
            f"unsupported weight bit width {bits}: choose from {SUPPORTED_BITS[0]} to {SUPPORTED_BITS[-1]}"
        )
    return bits


UNLESS_NONE = json_options(omit="none")


@dataclass(frozen=True)
class QuantisationReport:
    """How a fixed-point model was quantised and calibrated, and how far it is from the float network.

    The ``quantisation`` object of the model's JSON header. Every field is optional (None
    when not recorded), so headers written by older versions, which may lack some, load;
    keys this version does not know are kept in ``extra`` and written back unchanged, after the fields.
    """

    bits: int | None = None
    per_neuron: bool | None = None
    scale_method: str | None = None
    threshold_folding: bool | None = None
    shared_threshold: int | None = None
    rounding: str | None = None
    scale_exponent: int | None = None
    scale_multiplier_range: tuple[int, int] | None = None
    threshold_range: tuple[int, int] | None = None
    weight_max_abs_error: float | None = None
    weight_rmse: float | None = None
    weight_relative_rmse: float | None = None
    weights_clipped: int | None = None
    threshold_max_relative_error: float | None = None
    thresholds_clipped: int | None = None
    max_current: int | None = None  # max_j sum_i q_ij: the largest possible a_j
    calibration: str | None = None  # how S^R was obtained ("deployed (integer simulator)", "float (reused)", ...)
    calibration_saturations: int | None = None  # voltage clips while re-measuring S^R (None: not re-measured)
    # per module of an ensemble; absent from the JSON when not recorded (older headers are written back unchanged)
    module_weight_relative_rmse: tuple[float, ...] | None = field(default=None, metadata=UNLESS_NONE)
    module_weights_clipped: tuple[int, ...] | None = field(default=None, metadata=UNLESS_NONE)
    module_max_current: tuple[int, ...] | None = field(default=None, metadata=UNLESS_NONE)
    extra: Mapping[str, Any] = field(default_factory=dict, metadata=json_options(flatten=True))

    def to_dict(self) -> dict[str, Any]:
        return to_json_dict(self)  # it reads itself (from_dict), so it is no JsonDataclass

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> QuantisationReport:
        """The report of a header's ``quantisation`` object (a TypeError when it is not an object)."""
        if not isinstance(data, Mapping):
            raise TypeError(f"quantisation must be a JSON object, got {type(data).__name__}")
        known = {item.name for item in fields(cls)} - {"extra"}
        values: dict[str, Any] = {name: data[name] for name in known if name in data}
        for name in ("scale_multiplier_range", "threshold_range"):
            if values.get(name) is not None:
                low, high = values[name]
                values[name] = (int(low), int(high))
        kinds = {"module_weight_relative_rmse": float, "module_weights_clipped": int, "module_max_current": int}
        for name, kind in kinds.items():
            if values.get(name) is not None:
                values[name] = tuple(kind(value) for value in values[name])
        extra = {key: value for key, value in data.items() if key not in known}
        return cls(**values, extra=extra)


@dataclass
class FixedPointModel:
    """A quantised network, self-describing (every width, rounding and scale is in here)."""

    bits: int
    weight_mantissa: np.ndarray  # (inputs, neurons) int32 in [0, 2**bits - 1]
    scale_multiplier: np.ndarray  # (neurons,) int32 in [1, 2**16 - 1]; all equal when per-tensor
    scale_exponent: int  # w ~= q * m * 2**scale_exponent
    threshold: np.ndarray  # (neurons,) int32 in [1, 2**17 - 1]: vth mantissas
    decay_dv: int  # 12-bit voltage decay
    config: Config  # the source network's full config (encoder, T, beta, WTA, ...)
    calibration: np.ndarray  # (neurons, places) int64: S^R of this deployed network
    float_calibration: np.ndarray  # (neurons, places) int64: S^R of the float source network
    reference_place_ids: np.ndarray  # (places,) int64
    reference_traversals: list[str]
    quantisation: QuantisationReport  # per_neuron, scale_method, threshold_folding, errors, calibration
    source_sha256: str  # sha256 of the float checkpoint file
    data: dict[str, Any] = field(default_factory=dict)
    voltage_shift: int = VOLTAGE_SHIFT
    voltage_bits: int = VOLTAGE_BITS
    version: str = __version__

    def __post_init__(self) -> None:
        if isinstance(self.quantisation, Mapping):  # a header's JSON object (callers written before the type)
            self.quantisation = QuantisationReport.from_dict(self.quantisation)

    @property
    def n_inputs(self) -> int:
        return int(self.weight_mantissa.shape[0])

    @property
    def n_neurons(self) -> int:
        return int(self.weight_mantissa.shape[1])

    @property
    def voltage_limit(self) -> int:
        return (1 << (self.voltage_bits - 1)) - 1

    def wta_description(self) -> str:
        """The header's WTA rule in words (per module for an ensemble)."""
        if not self.config.network.wta:
            return "off: every candidate spikes"
        group = wta_group(self.config, self.n_neurons)
        if self.n_neurons == group:
            return "one spike: argmax over C of a_j * m_j, ties to the lowest index"
        return (
            f"one spike per module (groups of {group} consecutive neurons, {self.n_neurons // group} modules): "
            "argmax over the module's part of C of a_j * m_j, ties to the lowest index"
        )

    def header(self) -> dict[str, Any]:
        """The JSON header: every width, rounding rule and scale, for humans and other tools."""
        return {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "package_version": self.version,
            "source_sha256": self.source_sha256,
            "bits": self.bits,
            "scale_exponent": self.scale_exponent,
            "decay_dv": self.decay_dv,
            "voltage_shift": self.voltage_shift,
            "voltage_bits": self.voltage_bits,
            "quantisation": self.quantisation.to_dict(),
            "config": self.config.to_dict(),
            "reference_traversals": self.reference_traversals,
            "data": self.data,
            "arithmetic": {
                "weights": f"unsigned {self.bits}-bit mantissas q_ij; w_ij ~= q_ij * m_j * 2**scale_exponent",
                "scale_multiplier": f"unsigned {MULTIPLIER_BITS}-bit m_j per neuron (all equal within a module when "
                "per-tensor)",
                "threshold": f"unsigned {THRESHOLD_BITS}-bit vth mantissa, compared as vth << voltage_shift",
                "current": "a_j[t] = sum_i q_ij s_i[t] (exact integer)",
                "decay": "V <- trunc_toward_zero(V * (4096 - decay_dv) / 4096)",
                "voltage": f"V <- clip(V + (a << voltage_shift), -(2**{self.voltage_bits - 1} - 1), "
                f"2**{self.voltage_bits - 1} - 1), clips counted",
                "candidates": "C = {j : V_j > threshold_j << voltage_shift}",
                "wta": self.wta_description(),
                "reset": "V_j <- 0 for every j in C",
                "state": "V zeroed at the start of every presentation"
                if self.config.network.state_isolation
                else "V carried across presentations",
                "encoder": "s_i[t] ~ Bernoulli(clip(rate_scale * p_i, 0, 1)), "
                "keyed by (seed, stream, traversal, place_id)",
            },
        }


def save_fixed_point(path: str | Path, model: FixedPointModel) -> Path:
    """Validate and write a fixed-point model atomically (integer arrays + JSON header); returns the path."""
    path = require_path("path", path)
    validate(model, path)
    check_header(model.header(), path)  # the reader's own checks: nothing is written that it refuses
    arrays = {name: getattr(model, name).astype(np.int32 if k < 3 else np.int64) for k, name in enumerate(MODEL_ARRAYS)}
    return write_container(path, model.header(), arrays)  # the integer arrays int32, the counts and ids int64


def load_fixed_point(path: str | Path) -> FixedPointModel:
    """Read and validate a fixed-point model; ModelFileError names the file and the problem."""
    meta, arrays = read_container(path, "fixed-point model")  # the path as given: '' is named as empty, not '.'
    return model_from_header(meta, arrays, Path(path))


MODEL_ARRAYS: tuple[str, ...] = ("weight_mantissa", "scale_multiplier", "threshold", "calibration")
MODEL_ARRAYS += ("float_calibration", "reference_place_ids")
INTEGER_FIELDS = ("bits", "scale_exponent", "decay_dv", "voltage_shift", "voltage_bits")


def model_from_header(
    meta: Mapping[str, Any],
    arrays: Mapping[str, np.ndarray],
    path: Path,
    what: str = "fixed-point header",
    **fields: Any,
) -> FixedPointModel:
    """The model of a fixed-point header (:meth:`FixedPointModel.header`) and its arrays (:data:`MODEL_ARRAYS`),
    the one way every reader (.npz, NIR, Loihi-style) rebuilds a model: the header's checks
    (:func:`check_header`), then the model, then :func:`validate`. ``fields`` replace header values that a
    file states in its own terms (the Loihi description's bits, decay and voltage widths); ModelFileError
    naming ``path`` (``what``: the part of the file that is invalid)."""
    traversals, data = check_header(dict(meta), path)
    if set(MODEL_ARRAYS) - set(arrays):
        raise ModelFileError(f"fixed-point model lacks arrays {sorted(set(MODEL_ARRAYS) - set(arrays))}", path)
    try:
        values: dict[str, Any] = {
            **{key: meta[key] for key in INTEGER_FIELDS},  # integers: check_header
            "config": Config.from_dict(meta["config"]),
            "reference_traversals": traversals,
            "quantisation": QuantisationReport.from_dict(meta["quantisation"]),
            "source_sha256": str(meta["source_sha256"]),
            "data": data,
            "version": str(meta.get("package_version", "unknown")),
        }
        values |= {name: arrays[name] for name in MODEL_ARRAYS} | fields
        model = FixedPointModel(**values)
    except (KeyError, TypeError, ValueError, VprError) as exc:
        raise ModelFileError(f"invalid {what} ({exc})", path) from None
    validate(model, path)
    return model


def check_header(meta: dict[str, Any], path: Path) -> tuple[list[str], dict[str, str | None]]:
    """A fixed-point header's checks (format, integer fields, exponent range, source label, mappings, bits
    record); returns its reference traversals and data record. Run by the reader on what it reads and by
    the writer on what it is about to write; ModelFileError naming ``path``."""
    if meta.get("format") != FORMAT:
        raise ModelFileError(f"not a vprsnn fixed-point model (format {meta.get('format')!r})", path)
    if meta.get("format_version") != FORMAT_VERSION:
        raise ModelFileError(f"unsupported fixed-point format version {meta.get('format_version')!r}", path)
    traversals, data = reference_header(meta, path)
    for key in INTEGER_FIELDS:
        if not isinstance(meta.get(key), int) or isinstance(meta.get(key), bool):
            raise ModelFileError(f"invalid fixed-point header: {key} must be an integer, got {meta.get(key)!r}", path)
    if meta["bits"] not in SUPPORTED_BITS:
        raise ModelFileError(f"unsupported weight bit width {meta['bits']}", path)
    if not MIN_EXPONENT <= meta["scale_exponent"] <= MAX_EXPONENT:
        raise ModelFileError(
            f"scale_exponent {meta['scale_exponent']} is outside [{MIN_EXPONENT}, {MAX_EXPONENT}] "
            "(weights <= w_max give negative exponents)",
            path,
        )
    sha = meta.get("source_sha256")
    if not isinstance(sha, str) or not re.fullmatch(r"[!-~]{1,128}", sha):
        raise ModelFileError(f"source_sha256 must be a digest or label (1-128 printable characters), got {sha!r}", path)
    if not isinstance(meta.get("arithmetic", {}), dict) or not isinstance(meta.get("quantisation"), dict):
        raise ModelFileError("invalid fixed-point header: arithmetic and quantisation must be mappings", path)
    if meta["quantisation"].get("bits") not in (None, meta["bits"]):
        raise ModelFileError(
            f"the quantisation record says {meta['quantisation'].get('bits')!r} bits, the header {meta['bits']}", path
        )
    return traversals, data


def validate(model: FixedPointModel, path: Path) -> None:
    """Every array has its declared shape, an integer dtype, and values that fit their widths."""

    def fail(message: str) -> None:
        raise ModelFileError(message, path)

    if not isinstance(model, FixedPointModel):
        fail(f"not a FixedPointModel: a {type(model).__name__}")
    if isinstance(model.reference_traversals, str) or not isinstance(model.reference_traversals, list | tuple):
        fail(f"reference_traversals must be a list of traversal names, got {model.reference_traversals!r}")
    if model.bits not in SUPPORTED_BITS:
        fail(f"unsupported weight bit width {model.bits}")
    net = model.config.network
    n_places = validate_reference_ids(model.reference_place_ids, path)
    n_neurons = ensemble_neurons(model.config, n_places)  # M n: every module's neurons side by side
    limits = {  # name: (shape, lowest, highest); every shape and dtype is checked before any value
        "weight_mantissa": ((net.n_inputs, n_neurons), 0, (1 << model.bits) - 1),
        "scale_multiplier": ((n_neurons,), 1, (1 << MULTIPLIER_BITS) - 1),
        "threshold": ((n_neurons,), 1, (1 << THRESHOLD_BITS) - 1),
    }
    for name, (shape, _, _) in limits.items():
        array = getattr(model, name)
        if array.shape != shape:
            fail(f"{name} has shape {array.shape}, expected {shape}")
        if not np.issubdtype(array.dtype, np.integer):
            fail(f"{name} has dtype {array.dtype}, expected integers")
    for name, (_, low, high) in limits.items():
        array = getattr(model, name)
        if array.size and (array.min() < low or array.max() > high):
            fail(f"{name} values [{array.min()}, {array.max()}] do not fit [{low}, {high}]")
    per_module = model.scale_multiplier.reshape(-1, net.n_neurons)
    if model.quantisation.per_neuron is False and np.any(per_module != per_module[:, :1]):
        fail("per-tensor model with unequal scale multipliers within a module")
    if model.quantisation.threshold_folding and np.unique(model.threshold).size > 1:
        fail("threshold-folded model with unequal integer thresholds")
    if not 0 <= model.decay_dv < (1 << DECAY_BITS):
        fail(f"decay_dv {model.decay_dv} does not fit {DECAY_BITS} bits")
    if model.voltage_bits != VOLTAGE_BITS or not 0 <= model.voltage_shift < model.voltage_bits:
        fail(f"unsupported voltage format ({model.voltage_bits} bits, shift {model.voltage_shift})")
    for name in ("calibration", "float_calibration"):
        array = getattr(model, name)
        if array.shape != (n_neurons, n_places) or not np.issubdtype(array.dtype, np.integer) or (array < 0).any():
            fail(f"{name} must be non-negative integer counts of shape {(n_neurons, n_places)}")
