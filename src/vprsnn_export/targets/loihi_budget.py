"""How many Loihi-class cores and synapses a network needs (:func:`core_budget`; docs/targets.md §2.5)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.io.serial import JsonDataclass
from vprsnn_export.network.cost import CostSummary, query_cost
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


def axon_synapse_bits(limits: CoreLimits, neurons: int, bits: int) -> int:
    """Synaptic memory one input axon needs to reach ``neurons`` neurons of one core at ``bits`` bits.

    Loihi 1 (nengo-loihi): sum over groups of c <= 64 synapses of 64 ceil((c b + 10) / 64)
    Loihi 2 (dense):       neurons b   (no headers: a lower bound; neuron state shares the memory)

    Loihi 1 stores 1-6 or 8 weight bits (a 7-bit weight takes b = 8); Loihi 2's dense format any width.
    """
    if limits.charge == "dense":
        return neurons * bits
    b = 8 if bits == 7 else bits
    counts = (min(LOIHI1_GROUP, neurons - start) for start in range(0, neurons, LOIHI1_GROUP))
    return sum(LOIHI1_WORD_BITS * -(-(count * b + LOIHI1_GROUP_HEADER_BITS) // LOIHI1_WORD_BITS) for count in counts)


def neurons_per_core(limits: CoreLimits, inputs: int, bits: int) -> int:
    """The most neurons k of one module a core holds: k <= the neuron limit and inputs * axon_synapse_bits(k) <= memory."""
    if limits.fan_in_per_core is not None and inputs > limits.fan_in_per_core:
        raise InvalidValueError(
            f"{inputs} inputs exceed {limits.chip}'s fan-in of {limits.fan_in_per_core} axons per core"
        )
    sizes = range(1, limits.neurons_per_core + 1)
    over = (k for k in sizes if inputs * axon_synapse_bits(limits, k, bits) > limits.synapse_bits_per_core)
    best = next(over, sizes.stop) - 1  # the last k before the first that does not fit
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
    """The :class:`CoreBudget` of an ensemble on one Loihi-class chip family (the rule in its docstring); every count
    >= 1 (export --loihi-cores checks its shape)."""
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
    return [core_budget(modules, neurons, inputs, b, limits) for limits in LOIHI_CHIPS for b in bits]


def model_budgets(model: FixedPointModel) -> list[CoreBudget]:
    """The budget of ``model`` itself (its modules, neurons per module, inputs and bits) on each chip family."""
    modules = module_count(len(model.reference_place_ids), model.config.train.module_size)
    return budget_table(modules, model.config.network.n_neurons, model.n_inputs, (model.bits,))


@dataclass(frozen=True)
class OperationCosts:
    """Published per-operation energy and time of a chip (docs/targets.md, "Cost per query")."""

    chip: str
    synaptic_op_pj: float  # one synaptic event (an input spike reaching one neuron)
    neuron_update_pj: float  # one neuron's state update in one step
    synaptic_op_ns: float
    neuron_update_ns: float
    barrier_ns: float  # the step's end: every core waits for the others
    source: str


#: Davies et al. 2018, Table 2: pre-silicon figures (SDF and SPICE simulation at 0.75 V), not silicon measurements.
#: Every neuron here integrates input on every step, so the *active* neuron update is charged; the synaptic op is
#: the table's minimum energy and maximum time; the barrier is its 32-tile (one chip) value.
LOIHI1_OPERATIONS = OperationCosts(
    chip="Loihi 1",
    synaptic_op_pj=23.6,
    neuron_update_pj=81.0,
    synaptic_op_ns=3.5,
    neuron_update_ns=8.4,
    barrier_ns=465.0,
    source="Davies et al., Loihi: A Neuromorphic Manycore Processor with On-Chip Learning, IEEE Micro 38(1) 2018, "
    "Table 2 (pre-silicon): 23.6 pJ per synaptic spike op (min), 3.5 ns (max); 81 pJ and 8.4 ns per active neuron "
    "update; 113-465 ns mesh-wide barrier sync (1-32 tiles)",
)


@dataclass(frozen=True)
class QueryEstimate(JsonDataclass):
    """An *estimate* of one query's energy and latency on a chip from its per-operation figures (:func:`query_estimate`)."""

    chip: str
    steps: float
    synaptic_events: float
    neuron_updates: float
    energy_uj: float
    latency_ms: float
    source: str


def query_estimate(
    cost: CostSummary, budget: CoreBudget, operations: OperationCosts = LOIHI1_OPERATIONS
) -> QueryEstimate:
    """Energy and latency per query from the mean counts of ``cost`` and the cores of ``budget``:

        energy  = E e_syn + U e_neuron                                 (E synaptic events, U neuron updates)
        latency = S k t_syn + T (k t_neuron + t_barrier)               (S input spikes, T steps, k neurons per core)

    The cores run in parallel and each holds k neurons that every input reaches, so a step takes the time
    its busiest core needs for its input spikes' k synaptic ops and its k neuron updates, then the barrier.
    Static (leakage) power, spike routing and the host's input and readout are left out: an estimate, not a
    measurement.
    """
    k = budget.neurons_per_core
    energy_pj = cost.synaptic_events * operations.synaptic_op_pj + cost.neuron_updates * operations.neuron_update_pj
    latency_ns = cost.input_spikes * k * operations.synaptic_op_ns + cost.steps * (
        k * operations.neuron_update_ns + operations.barrier_ns
    )
    return QueryEstimate(
        chip=operations.chip,
        steps=cost.steps,
        synaptic_events=cost.synaptic_events,
        neuron_updates=cost.neuron_updates,
        energy_uj=energy_pj * 1e-6,
        latency_ms=latency_ns * 1e-6,
        source=operations.source,
    )


def deployment_cost(model: FixedPointModel, spikes: object | None = None, label: str = "") -> dict[str, Any]:
    """export.json's ``cost``: the steps, neuron updates and synaptic events per input spike of one query, and with
    ``spikes`` (N, T, I) the measured means and the :func:`query_estimate` on each chip with published figures.

        steps = T,  neuron updates = T J,  synaptic events = J per input spike   (J = M n: every input reaches all)
    """
    neurons = int(model.weight_mantissa.shape[1])
    steps = model.config.encoder.timesteps
    out: dict[str, Any] = {
        "steps": steps,
        "neuron_updates": steps * neurons,
        "synaptic_events_per_input_spike": neurons,
    }
    if spikes is None:
        return out
    cost = query_cost(spikes, neurons, places=len(model.reference_place_ids)).summary()
    budget = next(b for b in model_budgets(model) if b.chip == LOIHI1_OPERATIONS.chip)
    return {
        **out,
        "measured_on": label,
        "per_query": cost.to_dict(),
        "estimates": [query_estimate(cost, budget).to_dict()],
    }
