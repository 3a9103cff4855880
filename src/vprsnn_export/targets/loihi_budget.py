"""How many Loihi-class cores and synapses a network needs (:func:`core_budget`; docs/targets.md §2.5)."""

from __future__ import annotations

from dataclasses import dataclass

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.network.modules import module_count


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
