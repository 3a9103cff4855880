"""The deployed network as Loihi-convention fixed-point parameters (Lava's `fixed_pt` models).

Written into one folder:

    network.json   header: populations, connections, neuron parameters, WTA rule, input
                   source, timing, arithmetic, and the fixed-point model's own header
    network.npz    arrays named in the header (no pickle), sha256 recorded in the header; the
                   weight mantissas bit-packed, ``bits`` bits each (:mod:`targets.packing`,
                   the layout stated in the header's ``weights_storage``)
    network.net    lava-dl netx HDF5 (one dense CUBA layer, vThMant per neuron or one value)

Mapping (Lava `Dense` + `LIF`, bit-accurate models, per step):

    Dense:  weights w_ji = q_ij << (8 - bits) (8-bit mantissas, sign mode EXCITATORY),
            num_weight_bits = bits, weight_exp = -(8 - bits), so
            a_j = (sum_i w_ji s_i) >> (8 - bits) = sum_i q_ij s_i exactly; one step of delay
    LIF:    du = 4095 (u = a << 6 each step), dv = decay_dv, vth = theta_int_j (17 bits, << 6),
            bias_mant = 0, bias_exp = 0; v = clip(trunc0(v (4096 - dv) / 4096) + u), spike when
            v > vth << 6, v <- 0

Lava's LIF wraps u at 24 bits where the contract saturates v; the two agree while
a_j << 6 < 2**23, i.e. a_j < 131072 (the header's ``current_bound`` says whether the
model can reach it). Hard WTA is not expressible with Dense and LIF: the header describes
the rule as a readout after the LIF population (it only selects which candidate's spike is
emitted; every candidate still resets, so the LIF dynamics are the WTA-off ones), and
``tests/targets/lava_conformance/run_lava.py --wta`` implements it as a Lava process
(``WtaReadout``) fed by the LIF spikes and the Dense current.

Ensembles (src/vprsnn_export/modules.py): the M modules are M populations ``exc_m`` (the
header's ``modules``: neurons [m n, (m + 1) n), their region of places, their threshold
and current bounds), each with its own parameters and its own WTA (``wta.group_size`` = n).
Lava's Dense + LIF of the whole ensemble computes every module's WTA-off network at once
(the modules share the input and never interact), so ``exc`` stays one LIF process of M n
neurons and the arrays one (M n, inputs) matrix; a Lava user may equally build one Dense +
LIF per module from the rows [m n, (m + 1) n). :func:`core_budget` states how many
Loihi-class cores and synapses the ensemble needs (the rule and its sources: docs/targets.md).
"""

from __future__ import annotations

import io
import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vprsnn_export.config import wta_group
from vprsnn_export.errors import InvalidValueError, ModelFileError, VprError
from vprsnn_export.export.model import (
    DECAY_BITS,
    MODEL_ARRAYS,
    FixedPointModel,
    model_from_header,
    validate,
)
from vprsnn_export.fileio import atomic_write, atomic_write_bytes, atomic_write_text, parse_json, sha256_bytes
from vprsnn_export.modules import module_count, module_regions
from vprsnn_export.targets.packing import PACKING, describe_packing, pack_bits, unpack_bits
from vprsnn_export.version import __version__

FORMAT = "vprsnn-loihi"
FORMAT_VERSION = 2  # 2: weight mantissas bit-packed ("input_exc_mantissas"); 1: Lava weights as int32
READABLE_VERSIONS = (1, 2)
HEADER_NAME = "network.json"
ARRAYS_NAME = "network.npz"
NETX_NAME = "network.net"
LAVA_WEIGHT_BITS = 8  # Lava's Dense holds 8-bit weight mantissas
SIGN_MODE_EXCITATORY = 2  # lava.utils.weightutils.SignMode.EXCITATORY
DU_NO_CURRENT_MEMORY = 4095  # Lava adds 1: decay 4096/4096, u = a << 6 every step
U_WRAP_CURRENT = 1 << 17  # a_j >= 2**17 makes a << 6 reach 2**23, where Lava's u wraps
WEIGHTS_NAME = "input_exc_mantissas"  # version 2: packed mantissas q, (neurons, inputs)
WEIGHTS_NAME_V1 = "input_exc_weights"  # version 1: Lava weights q << (8 - bits), (neurons, inputs) int32
OTHER_ARRAYS = (
    "exc_vth",
    "exc_bias_mant",
    "wta_score_multiplier",
    "calibration",
    "float_calibration",
    "reference_place_ids",
)
ARRAY_NAMES = (WEIGHTS_NAME, *OTHER_ARRAYS)
WEIGHT_LAYOUT = "(target, source) = (neurons, inputs)"


@dataclass
class LoihiDescription:
    """The header and arrays of an exported description (what a Lava user loads)."""

    header: dict[str, Any]
    arrays: dict[str, np.ndarray]


def lava_weights(model: FixedPointModel) -> tuple[np.ndarray, int, int]:
    """(weights (neurons, inputs) int32 = q << (8 - bits), num_weight_bits, weight_exp = -(8 - bits))."""
    shift = LAVA_WEIGHT_BITS - model.bits
    return (model.weight_mantissa.T.astype(np.int32) << shift), model.bits, -shift


def mantissas_from_lava(weights: np.ndarray, weight_exp: int) -> np.ndarray:
    """Inverse of :func:`lava_weights`: q_ij = w_ji >> -weight_exp (exact: the low bits are zero)."""
    return (weights.astype(np.int32) >> -weight_exp).T.copy()


def weights_storage(model: FixedPointModel) -> dict[str, Any]:
    """The header object documenting the packed mantissas (layout, packing, how to get Lava's weights)."""
    storage = describe_packing(model.bits, (model.n_neurons, model.n_inputs), WEIGHT_LAYOUT)
    storage["holds"] = f"weight mantissas q_ji; Lava's Dense.weights = q << {LAVA_WEIGHT_BITS - model.bits}"
    return storage


def describe(model: FixedPointModel, *, source_sha256: str | None = None) -> LoihiDescription:
    """The Lava-convention description of ``model`` (see the module docstring)."""
    validate(model, Path("<fixed-point model>"))
    if model.bits > LAVA_WEIGHT_BITS:
        raise InvalidValueError(
            f"Lava's Dense holds {LAVA_WEIGHT_BITS}-bit weights; {model.bits}-bit mantissas do not fit"
        )
    _, num_weight_bits, weight_exp = lava_weights(model)
    cfg = model.config
    n_in, n = model.n_inputs, model.n_neurons
    bound = int(model.weight_mantissa.astype(np.int64).sum(axis=0).max())
    arrays = {
        WEIGHTS_NAME: pack_bits(model.weight_mantissa.T, model.bits),
        "exc_vth": model.threshold.astype(np.int32),
        "exc_bias_mant": np.zeros(n, dtype=np.int16),
        "wta_score_multiplier": model.scale_multiplier.astype(np.int32),
        "calibration": model.calibration.astype(np.int64),
        "float_calibration": model.float_calibration.astype(np.int64),
        "reference_place_ids": model.reference_place_ids.astype(np.int64),
    }
    uniform = bool(np.all(model.threshold == model.threshold[0]))
    header = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "package_version": __version__,
        "source_sha256": source_sha256 or model.source_sha256,
        "convention": "Lava bit-accurate fixed_pt models (lava.proc.dense Dense, lava.proc.lif LIF), lava-nc 0.10",
        "timing": {
            "timesteps": cfg.encoder.timesteps,
            "synaptic_delay_steps": 1,
            "state": (
                "set exc.v and exc.u to 0 before each presentation and let one silent step flush the Dense buffer"
                if cfg.network.state_isolation
                else "v carried across presentations"
            ),
        },
        "populations": [
            {
                "name": "input",
                "kind": "spike_source",
                "size": n_in,
                "encoder": {
                    "rule": "s_i[t] ~ Bernoulli(clip(rate_scale * p_i, 0, 1)), p_i the preprocessed pixel",
                    "rate_scale": cfg.encoder.rate_scale,
                    "timesteps": cfg.encoder.timesteps,
                    "seed": cfg.seed,
                    "keys": "one generator per presentation, keyed by (seed, stream, traversal, place_id)",
                    "preprocess": cfg.to_dict()["preprocess"],
                },
                "lava": "lava.proc.io.source.RingBuffer(data=spikes (784, steps)) or any 1-bit spike source",
            },
            {
                "name": "exc",
                "kind": "LIF",
                "size": n,
                "lava": "lava.proc.lif.process.LIF, run with select_tag='fixed_pt'",
                "du": DU_NO_CURRENT_MEMORY,
                "dv": model.decay_dv,
                "vth": "exc_vth",
                "vth_uniform": uniform,
                "bias_mant": "exc_bias_mant",
                "bias_exp": 0,
                "u_v_bits": model.voltage_bits,
                "vth_shift": model.voltage_shift,
                "activation_shift": model.voltage_shift,
                "reset": "v <- 0 for every neuron over threshold",
            },
        ],
        "connections": [
            {
                "name": "input_exc",
                "source": "input",
                "target": "exc",
                "lava": "lava.proc.dense.process.Dense",
                "weights": WEIGHTS_NAME,
                "layout": WEIGHT_LAYOUT,
                "weights_storage": weights_storage(model),
                "num_weight_bits": num_weight_bits,
                "weight_exp": weight_exp,
                "sign_mode": "EXCITATORY",
                "sign_mode_value": SIGN_MODE_EXCITATORY,
                "mantissa_encoding": f"w = q << {-weight_exp}; a = (sum w) >> {-weight_exp} = sum q exactly",
                "current_bound": bound,
                "u_wrap_possible": bound >= U_WRAP_CURRENT,
            }
        ],
        "modules": module_populations(model),
        "resources": [asdict(budget) for budget in model_budgets(model)],
        "wta": {
            "enabled": cfg.network.wta,
            "group_size": wta_group(cfg, model.n_neurons),
            "scope": cfg.network.wta_scope,
            "rule": (
                "per step and per group of group_size consecutive exc neurons (the whole ensemble, or one module), "
                "of the neurons that spiked "
                "in Lava (all candidates, all reset), emit only the one with the largest a_j * m_j, ties to the "
                "lowest index; a_j = sum_i q_ij s_i of the same step"
            ),
            "score_multiplier": "wta_score_multiplier",
            "in_lava": "not expressible with Dense/LIF: a readout process that reads exc.s_out and the Dense "
            "activation and forwards one spike (WtaReadout in tests/targets/lava_conformance/run_lava.py; "
            "docs/targets.md section 2.4)",
        },
        "readout": {
            "calibration": "calibration (neurons, places): S^R of the deployed network",
            "reference_place_ids": "reference_place_ids",
            "gamma": cfg.assignment.gamma,
        },
        "arithmetic": model.header()["arithmetic"],
        "fixed_point_model": model.header(),
        "netx": {"file": NETX_NAME, "vThMant": "one value" if uniform else "per neuron, shape (neurons,)"},
    }
    return LoihiDescription(header=header, arrays=arrays)


def module_populations(model: FixedPointModel) -> list[dict[str, Any]]:
    """One population per module: exc neurons [m n, (m + 1) n), its places, its own vth and current bound.

    Each is what one module's Lava LIF would hold: ``vth`` = exc_vth[neurons], ``dv`` the
    ensemble's, ``weights`` the rows [m n, (m + 1) n) of the connection's matrix.
    """
    group = model.config.network.n_neurons
    regions = module_regions(len(model.reference_place_ids), model.config.train.module_size)
    sums = model.weight_mantissa.astype(np.int64).sum(axis=0)
    rows = []
    for m, (start, stop) in enumerate(regions.tolist()):
        own = slice(m * group, (m + 1) * group)
        vth = model.threshold[own]
        rows.append(
            {
                "name": f"exc_{m}",
                "kind": "LIF",
                "neurons": [m * group, (m + 1) * group],
                "places": [int(start), int(stop)],
                "vth_range": [int(vth.min()), int(vth.max())],
                "vth_uniform": bool(np.all(vth == vth[0])),
                "score_multiplier_range": [
                    int(model.scale_multiplier[own].min()),
                    int(model.scale_multiplier[own].max()),
                ],
                "current_bound": int(sums[own].max()),
                "synapses": int(model.n_inputs * group),
            }
        )
    return rows


@dataclass(frozen=True)
class CoreLimits:
    """The per-core resources of a Loihi-class chip and how synaptic memory is charged (docs/targets.md §2.5)."""

    chip: str
    neurons_per_core: int  # compartments (Loihi 1) / neurons (Loihi 2) per core
    synapse_bits_per_core: int  # synaptic memory per core, bits
    fan_in_per_core: int | None  # input axons per core (None: no published limit)
    cores_per_chip: int
    synapses_per_chip: int
    charge: str  # "nengo-loihi": 64-synapse groups with a 10-bit header, 64-bit words; "dense": b bits per synapse
    source: str


LOIHI1 = CoreLimits(
    chip="Loihi 1",
    neurons_per_core=1024,
    synapse_bits_per_core=16384 * 64,
    fan_in_per_core=4096,
    cores_per_chip=128,
    synapses_per_chip=130_000_000,
    charge="nengo-loihi",
    source="Davies et al., IEEE Micro 38(1) 2018 (128 cores, 1024 compartments, 4096 fan-in axons per core); "
    "nengo-loihi block.py MAX_COMPARTMENTS/MAX_IN_AXONS/MAX_SYNAPSE_BITS = 1024/4096/16384*64 and "
    "SynapseConfig.bits_per_axon (dense synapse format)",
)
LOIHI2 = CoreLimits(
    chip="Loihi 2",
    neurons_per_core=8192,
    synapse_bits_per_core=192 * 1024 * 8,
    fan_in_per_core=None,
    cores_per_chip=128,
    synapses_per_chip=120_000_000,
    charge="dense",
    source="Intel Loihi 2 technology brief, 2021 (128 neuro cores, up to 1M neurons and 120M synapses per chip, "
    "8192 neurons and 192 KB of flexibly shared memory per core)",
)
LOIHI_CHIPS = (LOIHI1, LOIHI2)
LOIHI1_GROUP = 64  # synapses per group in one synaptic-memory entry (6-bit count field + 1)
LOIHI1_GROUP_HEADER_BITS = 10  # 4-bit format index + 6-bit synapse count
LOIHI1_WORD_BITS = 64


def stored_weight_bits(limits: CoreLimits, bits: int) -> int:
    """Loihi 1 stores 1-6 or 8 weight bits (a 7-bit weight takes 8); Loihi 2's dense format any width."""
    return 8 if limits.charge == "nengo-loihi" and bits == 7 else bits


def axon_synapse_bits(limits: CoreLimits, neurons: int, bits: int) -> int:
    """Synaptic memory one input axon needs to reach ``neurons`` neurons of one core at ``bits`` bits.

    Loihi 1 (nengo-loihi): sum over groups of c <= 64 synapses of 64 ceil((c b + 10) / 64)
    Loihi 2 (dense):       neurons b   (no headers: a lower bound; neuron state shares the memory)
    """
    b = stored_weight_bits(limits, bits)
    if limits.charge == "dense":
        return neurons * b
    total = 0
    for start in range(0, neurons, LOIHI1_GROUP):
        count = min(LOIHI1_GROUP, neurons - start)
        total += LOIHI1_WORD_BITS * -(-(count * b + LOIHI1_GROUP_HEADER_BITS) // LOIHI1_WORD_BITS)
    return total


def neurons_per_core(limits: CoreLimits, inputs: int, bits: int) -> int:
    """The most neurons k of one module a core holds: k <= the neuron limit and inputs * axon_synapse_bits(k) <= memory."""
    if limits.fan_in_per_core is not None and inputs > limits.fan_in_per_core:
        raise InvalidValueError(
            f"{inputs} inputs exceed {limits.chip}'s fan-in of {limits.fan_in_per_core} axons per core"
        )
    best = 0
    for k in range(1, limits.neurons_per_core + 1):
        if inputs * axon_synapse_bits(limits, k, bits) > limits.synapse_bits_per_core:
            break
        best = k
    if best == 0:
        raise InvalidValueError(f"one neuron with {inputs} {bits}-bit inputs does not fit a {limits.chip} core")
    return best


@dataclass(frozen=True)
class CoreBudget:
    """How many Loihi-class cores an ensemble of ``modules`` x ``neurons`` neurons x ``inputs`` inputs needs at ``bits``.

    Every module is split over ceil(n / k) cores of at most k neurons (each core receives all
    inputs; modules never share a core, so each keeps its own vth and its own WTA group):

        cores = M ceil(n / k),  chips = ceil(cores / cores_per_chip),  synapses = M n inputs
    """

    chip: str
    bits: int
    modules: int
    neurons_per_module: int
    inputs: int
    neurons_per_core: int  # k
    cores_per_module: int
    cores: int
    chips: int
    synapses: int
    synapse_bits_per_core: int  # what the fullest core uses
    synapse_bits_limit: int
    source: str


def core_budget(modules: int, neurons: int, inputs: int, bits: int, limits: CoreLimits = LOIHI1) -> CoreBudget:
    """The :class:`CoreBudget` of an ensemble on one Loihi-class chip family (the rule in its docstring)."""
    if min(modules, neurons, inputs) < 1:
        raise InvalidValueError(f"modules, neurons and inputs must be >= 1, got {modules}, {neurons}, {inputs}")
    k = min(neurons_per_core(limits, inputs, bits), neurons)
    per_module = -(-neurons // k)
    cores = modules * per_module
    return CoreBudget(
        chip=limits.chip,
        bits=bits,
        modules=modules,
        neurons_per_module=neurons,
        inputs=inputs,
        neurons_per_core=k,
        cores_per_module=per_module,
        cores=cores,
        chips=max(-(-cores // limits.cores_per_chip), -(-modules * neurons * inputs // limits.synapses_per_chip)),
        synapses=modules * neurons * inputs,
        synapse_bits_per_core=inputs * axon_synapse_bits(limits, k, bits),
        synapse_bits_limit=limits.synapse_bits_per_core,
        source=limits.source,
    )


def budget_table(modules: int, neurons: int, inputs: int, bits: tuple[int, ...]) -> list[CoreBudget]:
    """:func:`core_budget` for every chip family in LOIHI_CHIPS and every width in ``bits``."""
    return [core_budget(modules, neurons, inputs, b, limits) for limits in LOIHI_CHIPS for b in bits]


def model_budgets(model: FixedPointModel) -> list[CoreBudget]:
    """The budget of ``model`` itself (its modules, neurons per module, inputs and bits) on each chip family."""
    group = model.config.network.n_neurons
    modules = module_count(len(model.reference_place_ids), model.config.train.module_size)
    return budget_table(modules, group, model.n_inputs, (model.bits,))


def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    buffer = io.BytesIO()
    members: dict[str, Any] = dict(arrays)
    np.savez_compressed(buffer, **members)
    return buffer.getvalue()


def write_loihi(model: FixedPointModel, out_dir: str | Path, *, source_sha256: str | None = None) -> dict[str, Path]:
    """Write network.json, network.npz and network.net into ``out_dir``.

    The arrays go first and the header, which names their sha256, last: a reader never sees
    a header pointing at arrays that are not there yet.
    """
    out_dir = Path(out_dir)
    desc = describe(model, source_sha256=source_sha256)
    blob = npz_bytes(desc.arrays)
    desc.header["arrays"] = {"file": ARRAYS_NAME, "sha256": sha256_bytes(blob)}
    written = {"arrays": atomic_write_bytes(out_dir / ARRAYS_NAME, blob)}
    written["netx"] = write_netx(model, out_dir / NETX_NAME)
    written["header"] = atomic_write_text(out_dir / HEADER_NAME, json.dumps(desc.header, indent=2, sort_keys=True))
    return written


def write_netx(model: FixedPointModel, path: str | Path) -> Path:
    """lava-dl netx HDF5: ``layer/0`` a dense layer with a CUBA neuron, the mantissas as uint8 weights.

    The weight dataset is gzip-compressed (an HDF5 filter h5py reads transparently): about
    1.15 x bits per synapse at 2 and 4 bits instead of 8.

    netx maps CUBA to Lava's LIF with du = iDecay - 1, dv = vDecay and vth = vThMant (a
    scalar when every neuron shares the threshold, else the (neurons,) array, which Lava's
    LIF broadcasts), and re-derives num_weight_bits / weight_exp from the weights itself
    (exact for these non-negative integers).
    """
    import h5py

    uniform = bool(np.all(model.threshold == model.threshold[0]))
    vth = np.int64(model.threshold[0]) if uniform else model.threshold.astype(np.int64)

    def fill(handle) -> None:
        with h5py.File(handle, "w") as f:
            layer = f.create_group("layer").create_group("0")
            layer.create_dataset("type", data=np.bytes_("dense"))
            layer.create_dataset("shape", data=np.array([model.n_neurons], dtype=np.int64))
            weight = model.weight_mantissa.T.astype(np.uint8)
            layer.create_dataset("weight", data=weight, compression="gzip", compression_opts=9, shuffle=False)
            neuron = layer.create_group("neuron")
            neuron.create_dataset("type", data=np.bytes_("CUBA"))
            neuron.create_dataset("iDecay", data=np.int64(DU_NO_CURRENT_MEMORY + 1))
            neuron.create_dataset("vDecay", data=np.int64(model.decay_dv))
            neuron.create_dataset("vThMant", data=vth)
            neuron.create_dataset("refDelay", data=np.int64(1))
            neuron.create_dataset("gradedSpike", data=np.bool_(False))

    buffer = io.BytesIO()
    fill(buffer)
    return atomic_write(path, lambda handle: handle.write(buffer.getvalue()))


def header_path(path: str | Path) -> Path:
    path = Path(path)
    return path / HEADER_NAME if path.is_dir() else path


def read_loihi(path: str | Path) -> LoihiDescription:
    """Read and check a description (its folder or its network.json); defects are ModelFileErrors."""
    head = header_path(path)
    if not head.is_file():
        raise ModelFileError("no Loihi description here (network.json missing)", head)
    try:
        header = parse_json(head.read_bytes(), "network.json")
    except (UnicodeDecodeError, json.JSONDecodeError, InvalidValueError) as exc:
        raise ModelFileError(f"the description header is not valid JSON (truncated or corrupt: {exc})", head) from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        found = header.get("format") if isinstance(header, dict) else None
        raise ModelFileError(f"not a vprsnn Loihi description (format {found!r})", head)
    version = header.get("format_version")
    if version not in READABLE_VERSIONS:
        raise ModelFileError(
            f"unsupported Loihi description version {version!r} (this version reads {list(READABLE_VERSIONS)})", head
        )
    arrays_path = head.parent / str(header.get("arrays", {}).get("file", ARRAYS_NAME))
    if not arrays_path.is_file():
        raise ModelFileError("the arrays file named by the header is missing", arrays_path)
    blob = arrays_path.read_bytes()
    if sha256_bytes(blob) != header["arrays"].get("sha256"):
        raise ModelFileError(
            "the arrays file does not match the sha256 in network.json (truncated or replaced)", arrays_path
        )
    try:
        with np.load(io.BytesIO(blob), allow_pickle=False) as npz:
            arrays = {name: npz[name] for name in npz.files}
    except (ValueError, OSError, EOFError, KeyError) as exc:
        raise ModelFileError(f"unreadable arrays ({exc})", arrays_path) from None
    needed = (WEIGHTS_NAME if version == 2 else WEIGHTS_NAME_V1, *OTHER_ARRAYS)
    missing = sorted(set(needed) - set(arrays))
    if missing:
        raise ModelFileError(f"the arrays file lacks {missing}", arrays_path)
    desc = LoihiDescription(header=header, arrays=arrays)
    try:
        lava_weight_matrix(desc)
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise ModelFileError(f"the weights cannot be read ({type(exc).__name__}: {exc})", arrays_path) from None
    return desc


def lava_weight_matrix(desc: LoihiDescription) -> np.ndarray:
    """Lava's ``Dense.weights`` (neurons, inputs) int32 = q << -weight_exp, unpacked from either format version.

    Version 2 stores the mantissas q packed as its ``weights_storage`` states; version 1
    stored these weights as they are. A storage that does not match the header is a ValueError.
    """
    conn = desc.header["connections"][0]
    stored = desc.arrays[conn["weights"]]
    if desc.header.get("format_version") == 1:
        return stored.astype(np.int32)
    storage = conn["weights_storage"]
    bits, shape = int(storage["bits"]), tuple(int(n) for n in storage["shape"])
    if storage.get("packing") != PACKING or bits != int(conn["num_weight_bits"]):
        raise InvalidValueError(
            f"weights_storage must be {PACKING!r} at num_weight_bits = {conn['num_weight_bits']}, "
            f"got {storage.get('packing')!r} at {bits} bits"
        )
    mantissas = unpack_bits(stored, bits, shape).astype(np.int32)
    return mantissas << -int(conn["weight_exp"])


def description_to_model(desc: LoihiDescription, path: str | Path = "<Loihi description>") -> FixedPointModel:
    """Rebuild the fixed-point model from the Lava parameters (the round trip of the export)."""
    path = Path(path)
    try:
        fixed = desc.header["fixed_point_model"]
        conn = desc.header["connections"][0]
        exc = desc.header["populations"][1]
        arrays = {
            "weight_mantissa": mantissas_from_lava(lava_weight_matrix(desc), int(conn["weight_exp"])),
            "scale_multiplier": desc.arrays["wta_score_multiplier"].astype(np.int32),
            "threshold": desc.arrays["exc_vth"].astype(np.int32),
            **{name: desc.arrays[name].astype(np.int64) for name in MODEL_ARRAYS[3:]},
        }
        lava = {"bits": int(conn["num_weight_bits"]), "decay_dv": int(exc["dv"])}  # in the Lava parameters' terms
        lava |= {"voltage_shift": int(exc["vth_shift"]), "voltage_bits": int(exc["u_v_bits"])}
        model = model_from_header(fixed, arrays, path, "Loihi description's fixed-point header", **lava)
    except (KeyError, IndexError, TypeError, ValueError, VprError) as exc_:
        raise ModelFileError(f"incomplete Loihi description ({type(exc_).__name__}: {exc_})", path) from None
    if int(exc["du"]) != DU_NO_CURRENT_MEMORY or (1 << DECAY_BITS) <= model.decay_dv:
        raise ModelFileError("du must be 4095 and dv a 12-bit decay", path)
    validate(model, path)
    return model


def read_loihi_model(path: str | Path) -> FixedPointModel:
    """read_loihi + description_to_model."""
    return description_to_model(read_loihi(path), header_path(path))
