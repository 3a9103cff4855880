"""The one typed configuration: every hyperparameter of the method lives here.

It is written whole into every checkpoint, fixed-point model and report, and read
back from them; no other module holds a default for these values. Defaults follow
the paper's text (Sections III-IV), not its scripts (field notes §1).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from dataclasses import dataclass, field, fields, is_dataclass
from typing import Any

import dacite

from .data.preprocess import CHANNELS
from .errors import InvalidValueError


@dataclass(frozen=True)
class EncoderConfig:
    """Bernoulli rate code: s_i[t] ~ Bernoulli(clip(rate_scale * p_i, 0, 1)), t = 0..timesteps-1.

    ``input_gain`` (empty: none, the default) is the per-input gain g learnt from a second, unlabelled traversal
    (``train --adapt-from``, :mod:`vprsnn_export.trainer.adaptation`): the encoder then reads
    p_i = g_i x_i / max_j g_j x_j (0 for an image with no input left) instead of x_i. It is part of the model:
    learnt, not chosen, so it is written into the checkpoint and every exported file with the rest of this section.

    ``generator``: what draws the uniforms. ``"mt19937"`` (the default) is torch's CPU generator, one per
    presentation seed; ``"philox"`` is the counter-based Philox4x32-10 (:mod:`vprsnn_export.data.philox`), whose
    spikes are integer arithmetic of (seed, t, i) that a GPU draws in place and the CPU alike, bit for bit.
    """

    rate_scale: float = 0.25
    timesteps: int = 300
    input_gain: tuple[float, ...] = ()
    generator: str = "mt19937"


#: The encoder's uniform generators (``encoder.generator``) and the hard WTA's scopes (``network.wta_scope``).
GENERATORS = ("mt19937", "philox")
WTA_SCOPES = ("ensemble", "module")


@dataclass(frozen=True)
class PreprocessConfig:
    """Greyscale, resize to image_size x image_size (INTER_AREA), then the input channels.

    ``channels="intensity"`` (the paper): patch min-max normalisation, image_size**2 inputs.
    ``channels="dog_on_off"``: centre-surround (difference of Gaussians) ON and OFF channels,
    2 * image_size**2 inputs (docs/model.md, docs/research/recognition-quality.md).
    The choices are the registered channels (``preprocess.CHANNELS``).
    """

    image_size: int = 28
    patch_size: int = 7
    patch_norm: bool = True  # ablation switch: False scales the whole image to [0, 1] instead
    channels: str = "dog_on_off"  # the default since the sweep (docs/model.md); "intensity" is the paper's
    #: DoG centre and surround Gaussians, in pixels of the resized image. 0.7 / 1.4 since issue 20 (was 1 / 2): finer
    #: edges lift the whole route and the subset at k=1 (docs/research/route-recognition.md section 6).
    dog_sigma_centre: float = 0.7
    dog_sigma_surround: float = 1.4

    @property
    def n_channels(self) -> int:
        """The registered channel's number of channels (InvalidValueError for an unknown one)."""
        return CHANNELS.get(self.channels).n_channels

    @property
    def n_inputs(self) -> int:
        """What ``network.n_inputs`` must be: n_channels x image_size**2."""
        return self.n_channels * self.image_size * self.image_size


@dataclass(frozen=True)
class NetworkConfig:
    """One layer of discrete LIF neurons with hard WTA (paper eq. 1-4)."""

    n_inputs: int = 1568  # 2 channels (DoG ON, OFF) x 28 x 28; the paper's preset: 784
    n_neurons: int = 400
    beta: float = 0.95
    theta_init: float = 1.5
    wta: bool = True  # ablation switch: False lets every candidate spike
    #: Where the hard WTA picks its one winner per step when an ensemble runs (calibration, queries, every
    #: deployment target): "ensemble" = over all neurons of all modules, so modules compete and a query's
    #: spikes go to the modules that match it; "module" = within each module's n neurons. Training always
    #: uses one WTA per module (each module learns its own region). Same thing for a single network.
    #: Chosen on the whole route (docs/research/route-recognition.md): a file without this key is "module".
    wta_scope: str = "ensemble"
    state_isolation: bool = True  # ablation switch: False carries V across presentations in order


@dataclass(frozen=True)
class STDPConfig:
    """Trace STDP with soft bounds (paper eq. 5-7) and column L2 normalisation."""

    a_plus: float = 5e-4
    a_minus: float = 5e-6
    tau_pre: float = 15.0
    tau_post: float = 15.0
    w_max: float = 1.0
    weight_norm: bool = True  # ablation switch: column L2 normalisation after each update


@dataclass(frozen=True)
class HomeostasisConfig:
    """Global homeostasis theta_j += eta (rbar_j - r_target) once per batch (paper eq. 8)."""

    enabled: bool = True  # ablation switch
    # Per batch. The paper's code adds 0.001 (rbar_j[t] - r_target) at every one of the T = 300 steps, eta_batch = 0.3;
    # its text's 0.001 once per batch (the paper preset) leaves thresholds within 0.002 of theta_init. 1: research log §12.
    eta: float = 1.0
    r_target: float = 0.01
    theta_min: float = 0.6
    theta_max: float = 100.0


@dataclass(frozen=True)
class TrainConfig:
    epochs: int = 60  # chosen from the measured curve in docs/results/epochs.md
    batch_size: int = 64
    module_size: int = 0  # places per module (src/vprsnn_export/network/modules.py); 0: one network for all places
    #: The window and rate scale STDP learns with (0: the encoder's). The encoder section is the window the network
    #: is calibrated, queried and deployed with, so a network can learn at a long window and run at a short one.
    timesteps: int = 0
    rate_scale: float = 0.0


@dataclass(frozen=True)
class AssignmentConfig:
    """Weighted assignment involvement threshold gamma (paper eq. 9); the ensemble's region regularisation.

    An ensemble's readout (src/vprsnn_export/readout/regions.py, docs/readout.md; a single network is
    never changed): ``outside_weight`` = lambda scales each neuron's calibration responses to places
    outside its module's region (0: region-specific assignment, 1: whole route); ``hyperactive_share``
    = rho: a neuron that fires, during calibration, for more than this share of the places outside its
    region is silenced (1: none is). Chosen on the whole route (docs/results/route.md).
    """

    gamma: float = 0.02
    hyperactive_share: float = 0.5
    outside_weight: float = 0.0


@dataclass(frozen=True)
class EarlyConfig:
    """Early decision (readout/early.py, docs/results/cost.md): stop a query's simulation when its outcome is settled.

    ``margin``: stop at the first step t where the leading place's votes exceed the second's by more than the
    most the remaining T - t steps can add to any place. ``spikes`` > 0: stop once that many output spikes
    have been emitted. Both off (the default): every query runs all T steps.
    """

    margin: bool = False
    spikes: int = 0


#: Sections that are written into a file only when they differ from their defaults, so that files written
#: before they existed (and files that do not use them) stay byte-identical; a missing section reads as its defaults.
OPTIONAL_SECTIONS = ("early",)
#: Keys written only when they differ from their defaults, for the same reason (section -> keys).
OPTIONAL_KEYS = {"train": ("timesteps", "rate_scale"), "encoder": ("input_gain", "generator")}


@dataclass(frozen=True)
class VerifyConfig:
    """How ``verify`` judges a deployed network against float (docs/verify.md, readout/paired.py).

    Not a section of :class:`Config`: these settings judge a network and never change one, so a
    checkpoint's bytes do not depend on them; every verify report writes them into its settings.
    ``confidence``: level of every paired interval; ``resamples``: paired bootstrap resamples;
    ``seed``: the bootstrap's random generator seed (the verdict is deterministic).
    """

    confidence: float = 0.95
    resamples: int = 2000
    seed: int = 0

    def __post_init__(self) -> None:
        _check_ranges(self, "verify.")

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> VerifyConfig:
        """Rebuild the settings; unknown keys are an error, missing keys take the defaults."""
        return _build(cls, data, "verify")


@dataclass(frozen=True)
class Config:
    seed: int = 42
    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    preprocess: PreprocessConfig = field(default_factory=PreprocessConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)
    stdp: STDPConfig = field(default_factory=STDPConfig)
    homeostasis: HomeostasisConfig = field(default_factory=HomeostasisConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    assignment: AssignmentConfig = field(default_factory=AssignmentConfig)
    early: EarlyConfig = field(default_factory=EarlyConfig)

    def __post_init__(self) -> None:
        _check_ranges(self, "")
        pre, home = self.preprocess, self.homeostasis
        for key, value, allowed in (
            ("preprocess.channels", pre.channels, CHANNELS.names()),
            ("encoder.generator", self.encoder.generator, GENERATORS),
            ("network.wta_scope", self.network.wta_scope, WTA_SCOPES),
        ):
            if value not in allowed:
                raise InvalidValueError(f"config.{key}: {value!r} is not one of {', '.join(allowed)}")
        if pre.dog_sigma_centre >= pre.dog_sigma_surround:
            raise InvalidValueError("config.preprocess.dog_sigma_centre must be below dog_sigma_surround")
        if pre.image_size % pre.patch_size:
            raise InvalidValueError(
                f"preprocess.image_size {pre.image_size} is not a multiple of preprocess.patch_size {pre.patch_size}"
            )
        inputs = pre.n_inputs
        if self.network.n_inputs != inputs:
            raise InvalidValueError(
                f"network.n_inputs {self.network.n_inputs} must equal {pre.n_channels} channel(s) x "
                f"image_size**2 = {inputs} (preprocess.channels = {pre.channels!r})"
            )
        gain = self.encoder.input_gain
        if gain and (len(gain) != inputs or not all(math.isfinite(g) and g >= 0 for g in gain) or not any(gain)):
            raise InvalidValueError(
                f"config.encoder.input_gain: expected {inputs} finite non-negative gains, not all 0, got {len(gain)} "
                "values" + ("" if len(gain) != inputs else " with a negative, non-finite or all-zero gain")
            )
        if home.theta_min > home.theta_max:
            raise InvalidValueError(f"homeostasis.theta_min {home.theta_min} exceeds theta_max {home.theta_max}")

    def to_dict(self) -> dict[str, Any]:
        """Every section, except an :data:`OPTIONAL_SECTIONS` one at its defaults (left out, read back as them)."""
        data, default = dataclasses.asdict(self), dataclasses.asdict(Config())
        for name in OPTIONAL_SECTIONS:
            if data[name] == default[name]:
                del data[name]
        for name, keys in OPTIONAL_KEYS.items():
            data[name] = {k: v for k, v in data[name].items() if k not in keys or v != default[name][k]}
        return data

    @property
    def training_encoder(self) -> EncoderConfig:
        """The encoder STDP learns with: ``train.timesteps`` and ``train.rate_scale`` where set, else the encoder's."""
        return dataclasses.replace(
            self.encoder,
            timesteps=self.train.timesteps or self.encoder.timesteps,
            rate_scale=self.train.rate_scale or self.encoder.rate_scale,
        )

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Config:
        """Rebuild a Config; unknown keys are an error, missing keys take the defaults.

        Except ``network.wta_scope``: a file written before it existed ran every ensemble with one WTA per
        module (its calibration S^R was counted that way), so a missing key reads as ``"module"``.
        """
        if isinstance(data, dict) and isinstance(data.get("network"), dict) and "wta_scope" not in data["network"]:
            data = {**data, "network": {**data["network"], "wta_scope": "module"}}
        return _build(cls, data, "config")

    def replace(self, **dotted: Any) -> Config:
        """Copy with overrides given as dotted names: ``cfg.replace(**{"encoder.timesteps": 150})``."""
        data = dataclasses.asdict(self)
        for name, value in dotted.items():
            *sections, key = name.split(".")
            if not all((*sections, key)):
                raise InvalidValueError(f"config key {name[:80]!r}: an empty name between dots")
            target = data
            for part in sections:
                if part not in target or not isinstance(target[part], dict):
                    raise InvalidValueError(f"unknown config section {name[:80]!r}")
                target = target[part]
            if key not in target:
                raise InvalidValueError(f"unknown config key {name[:80]!r}")
            if isinstance(target[key], dict):
                raise InvalidValueError(
                    f"config key {name!r} is a section: set its keys one by one ({name}.{next(iter(target[key]), 'KEY')}=...)"
                )
            target[key] = value
        return Config.from_dict(data)


#: Allowed values of every numeric setting: (lowest, highest, lowest allowed itself, highest allowed itself).
#: Values outside, NaN and infinities are refused with a message naming the key.
RANGES: dict[str, tuple[float, float, bool, bool]] = {
    "seed": (0, 2**63 - 1, True, True),
    "encoder.rate_scale": (0.0, 1e6, False, True),
    "encoder.timesteps": (1, 100_000, True, True),
    "preprocess.image_size": (1, 4096, True, True),
    "preprocess.patch_size": (1, 4096, True, True),
    "preprocess.dog_sigma_centre": (0.0, 100.0, False, True),
    "preprocess.dog_sigma_surround": (0.0, 100.0, False, True),
    "network.n_inputs": (1, 2**24, True, True),
    "network.n_neurons": (1, 1_000_000, True, True),
    "network.beta": (0.0, 1.0, False, True),
    "network.theta_init": (0.0, 1e9, False, True),
    "stdp.a_plus": (0.0, 1e6, True, True),
    "stdp.a_minus": (0.0, 1e6, True, True),
    "stdp.tau_pre": (0.0, 1e9, False, True),
    "stdp.tau_post": (0.0, 1e9, False, True),
    "stdp.w_max": (0.0, 1e9, False, True),
    "homeostasis.eta": (0.0, 1e6, True, True),
    "homeostasis.r_target": (0.0, 1.0, True, True),
    "homeostasis.theta_min": (0.0, 1e9, False, True),
    "homeostasis.theta_max": (0.0, 1e9, False, True),
    "train.epochs": (0, 100_000, True, True),
    "train.batch_size": (1, 1_000_000, True, True),
    "train.module_size": (0, 10_000_000, True, True),
    "train.timesteps": (0, 100_000, True, True),
    "train.rate_scale": (0.0, 1e6, True, True),
    "assignment.gamma": (0.0, 1.0, True, True),
    "assignment.hyperactive_share": (0.0, 1.0, True, True),
    "assignment.outside_weight": (0.0, 1.0, True, True),
    "early.spikes": (0, 100_000_000, True, True),
    "verify.confidence": (0.0, 1.0, False, False),
    "verify.resamples": (1, 1_000_000, True, True),
    "verify.seed": (0, 2**63 - 1, True, True),
}


def wta_group(cfg: Config, n_neurons: int) -> int:
    """The neurons among which the hard WTA picks one winner per step when ``n_neurons`` neurons run.

    .. math:: G = \\begin{cases} M n & \\text{wta\\_scope = ensemble (all neurons)} \\\\
                                  n & \\text{wta\\_scope = module (n = network.n\\_neurons)} \\end{cases}

    Calibration, queries and every deployed implementation use this group; training always uses n.
    """
    return n_neurons if cfg.network.wta_scope == "ensemble" else cfg.network.n_neurons


def _check_ranges(section: Any, prefix: str) -> None:
    """InvalidValueError naming the key when a numeric setting of the dataclass ``section`` (a nested section's
    as ``section.key``) is NaN, infinite or outside :data:`RANGES`."""
    for item in fields(section):
        key, value = prefix + item.name, getattr(section, item.name)
        if is_dataclass(value):
            _check_ranges(value, f"{key}.")
        if isinstance(value, bool) or key not in RANGES:  # a section's name is not in it
            continue
        low, high, low_ok, high_ok = RANGES[key]
        number = float(value)
        if math.isnan(number) or math.isinf(number):
            raise InvalidValueError(f"config.{key}: expected a finite number, got {value!r}")
        below = number < low or (number == low and not low_ok)
        above = number > high or (number == high and not high_ok)
        if below or above:
            interval = f"{'[' if low_ok else '('}{low:g}, {high:g}{']' if high_ok else ')'}"
            raise InvalidValueError(f"config.{key}: {value!r} is outside {interval}")


#: What a setting of each type must be, in the words of the error that names it.
_EXPECTED = {int: "an integer", float: "a number", bool: "true/false", str: "a name (text)", tuple: "a list of numbers"}


def _integer(value: Any) -> Any:
    """An integral float as an int (2.0 -> 2); a bool or a fractional or non-finite float is refused."""
    if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
        raise dacite.WrongTypeError(field_type=int, value=value)
    return int(value) if isinstance(value, float) else value


def _number(value: Any) -> Any:
    """An int, a float or numeric text as a float; a bool, other text or any other value is refused."""
    if isinstance(value, int | float | str) and not isinstance(value, bool):
        with contextlib.suppress(ValueError):
            return float(value)
    raise dacite.WrongTypeError(field_type=float, value=value)


def _numbers(value: Any) -> Any:
    """A list or tuple of numbers as a tuple of floats (``encoder.input_gain``); anything else is refused."""
    if not isinstance(value, list | tuple):
        raise dacite.WrongTypeError(field_type=tuple, value=value)
    return tuple(_number(v) for v in value)


_READ = dacite.Config(strict=True, type_hooks={int: _integer, float: _number, tuple[float, ...]: _numbers})


def _build(cls: type, data: Any, where: str) -> Any:
    """``cls`` read by dacite (missing keys take the defaults); one InvalidValueError naming the key and the problem."""
    if not isinstance(data, dict):
        raise InvalidValueError(f"{where}: expected a mapping, got {type(data).__name__}")
    try:
        return dacite.from_dict(cls, data, _READ)
    except dacite.WrongTypeError as exc:
        wanted = _EXPECTED.get(exc.field_type, "a mapping")  # not a setting's type: a section's
        got = type(exc.value).__name__ if wanted == "a mapping" else repr(exc.value)
        raise InvalidValueError(f"{where}.{exc.field_path}: expected {wanted}, got {got}") from None
    except dacite.UnexpectedDataError as exc:  # raised without its section: the section holding the keys
        section = next((f".{name}" for name, v in data.items() if isinstance(v, dict) and exc.keys <= v.keys()), "")
        raise InvalidValueError(f"{where}{section}: unknown keys {sorted(exc.keys)}") from None


#: Named starting points for the config (``--preset``): the paper's constants, and the
#: illumination-invariant DoG ON/OFF input channels (docs/research/recognition-quality.md).
PRESETS: dict[str, dict[str, Any]] = {
    "paper": {"preprocess.channels": "intensity", "network.n_inputs": 28 * 28, "homeostasis.eta": 0.001},
    "dog": {},
    # Issue 30: one neuron per place in modules of 100, learnt at T = 300 (rate 0.25) and run at T = 80 (rate 0.375):
    # 9.98 M synaptic events per query on the 2400-place route (the default: 99.8 M); research log §13.
    "lean": {
        "network.n_neurons": 100,
        "train.module_size": 100,
        "encoder.timesteps": 80,
        "encoder.rate_scale": 0.375,
        "train.timesteps": 300,
        "train.rate_scale": 0.25,
    },
}


def preset(name: str) -> Config:
    """The config of a named preset; InvalidValueError listing the presets otherwise."""
    if name not in PRESETS:
        raise InvalidValueError(f"--preset: unknown preset {name!r}; choose from {', '.join(PRESETS)}")
    return Config().replace(**PRESETS[name])
