"""What each consumer of a written file computes, in one sentence or three (export.json's ``consumers``).

One function per deployment target, named by its registry entry (:mod:`targets.registry`, which
hands each the write options it reads): ``network`` is what was exported (a float checkpoint or
a fixed-point model) and ``model`` the fixed-point model the integer targets got.
"""

from __future__ import annotations

import numpy as np

from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.network.modules import module_count
from vprsnn_export.targets.loihi_budget import model_budgets
from vprsnn_export.targets.nir_semantics import float_consumers
from vprsnn_export.targets.onnx_target import WPROB_ROUNDING
from vprsnn_export.targets.registry import Network, WriteOptions


def ensemble_sentence(network: Network) -> str:
    """The sentence an ensemble adds to every statement ("" for a single network)."""
    group = network.config.network.n_neurons
    modules = module_count(len(network.reference_place_ids), network.config.train.module_size)
    where = (
        "over the whole ensemble (one winner per step among all neurons; network.wta_scope = ensemble)."
        if network.config.network.wta_scope == "ensemble"
        else "within each module (one winner per module per step; network.wta_scope = module)."
    )
    return (
        f" The network is an ensemble of {modules} modules of {group} neurons side by side; the hard WTA runs {where}"
        if modules > 1
        else ""
    )


def nir_statement(network: Network, model: FixedPointModel | None, options: WriteOptions) -> str:
    """NIR: read_nir rebuilds the network; a metadata-blind consumer computes what this sentence says."""
    wta_node, inhibition = options.wta_node, options.inhibition
    thresholds = network.thresholds if isinstance(network, Checkpoint) else network.threshold
    uniform = bool(np.all(thresholds == thresholds[0]))
    ensemble = ensemble_sentence(network)
    statement = float_consumers(network)
    verdict = (
        f"Float NIR consumers (NIR's LIF/IF in float32 or float64, Norse, SpikingJelly) compute this {statement['mode']} "
        "file exactly: " + statement["cause"]
        if statement["exact"]
        else f"Float NIR consumers do not compute this {statement['mode']} file exactly: {statement['cause']} "
        "(docs/targets.md section 1.4 gives the measured raster differences and decision agreement per bit width; "
        "quantize --non-leaky gives a file they compute exactly)"
    )
    arithmetic = (
        "the float network's own arithmetic"
        if isinstance(network, Checkpoint)
        else "float arithmetic on integer mantissas (no round-toward-zero decay, no 24-bit saturation)"
    )
    inhibit = (
        f"plus lateral inhibition ({inhibition} of its threshold per other spike, one step later)"
        if wta_node and inhibition > 0
        else "with no inhibition"
    )
    return (
        "vprsnn-export's read_nir rebuilds the network exactly (WTA from the metadata). A consumer that reads "
        f"only the nodes (nirtorch with NIR's LIF, snnTorch, Norse) computes {arithmetic}, every neuron over "
        f"threshold spiking (no WTA) {inhibit}"
        + (
            ""
            if wta_node
            else "; vx.apply_readout_rule(graph, input spikes, its spikes) turns that into the network's raster "
            "(the hard WTA, stated as metadata['readout_rule'])"
        )
        + ". At dt = 1e-4 s Euler gives "
        "v <- beta v + I; Norse ignores r (multiply v_threshold by its gain dt/tau before from_nir(graph, "
        "dt=1e-4)); SpikingJelly fires at v >= threshold (set the threshold to the next float32 above it); "
        "metadata['consumer_settings'] states both; snnTorch's and SpikingJelly's importers need one threshold "
        f"for all neurons ({'met' if uniform else 'not met by this model'})"
        + (
            ""
            if not wta_node
            else "; snnTorch's importer starves a LIF with a recurrent Linear and Norse returns "
            "the wta node's output instead of the spikes (the default graph, without --nir-wta-node, avoids both)"
        )
        + ". "
        + verdict
        + f". export --check fails when a consumer's decisions (+ readout rule) agree with the network's on fewer than "
        f"{statement['decision_tolerance']:.0%} of the queries (metadata['float_consumers'])."
        + (
            ensemble
            and ensemble + " metadata['populations'] lists the modules; the readout rule's group_size is the WTA group."
        )
    )


def onnx_statement(network: Network, model: FixedPointModel | None, options: WriteOptions) -> str:
    """ONNX: onnxruntime computes the integer network exactly."""
    return (
        "onnxruntime computes the integer network exactly: spike counts, raster and saturations identical to the "
        "integer simulator; the W+Prob head (float64, another summation order) gives the same decisions, its "
        f"probabilities within {WPROB_ROUNDING:g} of the numpy readout (measured: below 1e-15)."
        + (
            (ensemble := ensemble_sentence(network))
            and ensemble
            + " The input modules = [first, last) runs those modules alone (a tracking localiser's search "
            "window, metadata vprsnn.search), as the integer simulator does."
        )
    )


def loihi_statement(network: Network, model: FixedPointModel | None, options: WriteOptions) -> str | None:
    """Loihi-style description: what Lava's Dense + LIF compute, and the cores the network needs (``model``: the
    fixed-point model written, never None for an integer-only target)."""
    assert model is not None
    ensemble = ensemble_sentence(network)
    return (
        "Lava's bit-accurate Dense + LIF (fixed_pt) compute the candidate raster bit for bit (WTA off) while "
        "a_j < 2**17; the hard WTA is a rule in network.json that a Lava user adds after the LIF population."
        + (
            ensemble
            and ensemble
            + " network.json's modules are the populations exc_m, one per module; a tracking localiser (localize "
            "--search-window w, network.json's search rule) powers per frame only the cores of the modules its window "
            f"meets, at most ceil(w / {network.config.train.module_size}) + 1 modules, and each decision names them."
        )
        + " Loihi-class cores: "
        + "; ".join(
            f"{budget.chip} {budget.cores} cores ({budget.cores_per_module} per module), {budget.synapses:,} synapses"
            for budget in model_budgets(model)
        )
        + " (network.json resources; docs/targets.md §2.5)."
        + f" Per query: {model.config.encoder.timesteps} steps, {model.weight_mantissa.shape[1]:,} synaptic events per "
        "input spike; export.json's cost gives the events and an energy and latency estimate from published "
        "per-operation figures (docs/targets.md, Cost per query)."
    )
