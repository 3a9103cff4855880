"""NIR export of the network, built as a ``nir.NIRGraph`` directly (read back: :mod:`.nir_read`).

Graph (node names are fixed; edges (src, dst)):

    input --> linear --> lif --> output          Input(inputs), Linear(weight[neurons, inputs]),
                          ^  |                   LIF(tau, r, v_leak=0, v_threshold per neuron, v_reset=0)
                          +--wta <--+            Linear "wta" [neurons, neurons]: lateral inhibition

Parameters, with dt = DT_SECONDS (the value snnTorch uses) stated in the metadata:

    tau = dt / (1 - beta),  r = 1 / (1 - beta),  v_leak = 0,  v_reset = 0
    forward Euler at dt:    v <- v + dt/tau ((v_leak - v) + r I) = beta v + I      (exactly the network)
    beta = 1 (no leak):     an IF node (dv/dt = r I, r = 1 / dt) instead of a LIF: v <- v + I

Float checkpoint: the Linear holds the float32 weights w_ij and the LIF the float32
thresholds theta_j. Fixed-point model: the Linear holds the integer mantissas q_ij and the
LIF the integer threshold mantissas theta_int_j, with beta = (4096 - dv) / 4096; every
neuron's voltage then lives in its own mantissa units (the Loihi voltage divided by
2**voltage_shift), and the per-neuron scales m_j 2**e, which only the WTA comparison
needs, are in the metadata. Hard WTA has no NIR primitive: the metadata states the rule
(every neuron over threshold resets to 0, and of those only the one with the largest
a_j m_j, float: I_j, emits a spike), and the recurrent ``wta`` Linear approximates it for
consumers that ignore the metadata, as lateral inhibition one step late:

    W_wta[j, i] = -k v_threshold_j  (i != j),  k = WTA_INHIBITION = 1 by default

With k = 0 such a consumer computes the WTA-off network (every candidate spikes, a
superset of the network's spikes). ``wta_node=False`` leaves the node out for importers
that mishandle recurrent graphs (snnTorch 1.0, Norse 1.1). Metadata-blind consumers run
the file in :mod:`.nir_runners`.
"""

from __future__ import annotations

import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vprsnn_export.arguments import real_number, require_path
from vprsnn_export.config import wta_group
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import DECAY_BITS, FixedPointModel, validate
from vprsnn_export.io.checkpoint import Checkpoint, checkpoint_header, validate_checkpoint
from vprsnn_export.io.fileio import atomic_write_bytes, parse_json
from vprsnn_export.network.modules import module_count, module_regions
from vprsnn_export.targets.contract import decision_rule, encoder_contract
from vprsnn_export.targets.nir_semantics import WTA_INHIBITION, float_consumers, integer_semantics
from vprsnn_export.version import __version__

FORMAT = "vprsnn-nir"
FORMAT_VERSION = 1
DT_SECONDS = 1e-4
NODES = ("input", "linear", "lif", "wta", "output")
PLAIN_EDGES = [("input", "linear"), ("linear", "lif"), ("lif", "output")]
EDGES = PLAIN_EDGES + [("lif", "wta"), ("wta", "lif")]

Source = Checkpoint | FixedPointModel
#: The W+Prob distribution of a single network's output counts c (neurons,), as the project computes it
#: (:mod:`vprsnn_export.readout.assignment`, eq. 9-13); stated in the metadata for consumers without the project.
WPROB_RULE = (
    "S = calibration (neurons, places) as float64, gamma from header_json assignment.gamma, c the counts (float64); "
    "omega_j = #{l: S_jl > 0}; S1_jl = S_jl / omega_j where omega_j > gamma * places, else S_jl; "
    "S2_jl = S1_jl * S_jl / sum_m S_jm (0 for a silent row); "
    "score_l = (c S2)_l * ([c > 0] S)_l / sum_j S_jl (0 where that sum is 0); "
    "P = (score - min score) / (max score - min score), then P / sum P; uniform 1 / places where max == min. "
    "An ensemble (modules > 1) first regularises S by its regions (vprsnn_export.readout.regions)"
)


def effective_beta(source: Source) -> float:
    """Float: the config's beta. Fixed point: (4096 - dv) / 4096, what the integer decay multiplies by."""
    if isinstance(source, FixedPointModel):
        return ((1 << DECAY_BITS) - source.decay_dv) / (1 << DECAY_BITS)
    return float(source.config.network.beta)


def lif_node(beta: float, thresholds: np.ndarray, dt: float):
    """LIF with tau = dt / (1 - beta), r = 1 / (1 - beta); an IF with r = 1 / dt when beta = 1.

    NIR's IF is dv/dt = r I: forward Euler at dt gives v <- v + (dt r) I = v + I, since
    dt * (1 / dt) == 1 exactly in float32 and float64 for dt = 1e-4.
    """
    import nir

    n = thresholds.shape[0]
    zeros = np.zeros(n, dtype=np.float64)
    if beta >= 1.0:
        return nir.IF(r=np.full(n, 1.0 / dt), v_threshold=thresholds, v_reset=zeros)
    return nir.LIF(
        tau=np.full(n, dt / (1.0 - beta)),
        r=np.full(n, 1.0 / (1.0 - beta)),
        v_leak=zeros,
        v_threshold=thresholds,
        v_reset=zeros.copy(),
    )


def wta_rule(source: Source) -> str:
    if not source.config.network.wta:
        return "off: every neuron over threshold spikes"
    score = (
        "I_j" if isinstance(source, Checkpoint) else "a_j * m_j (integer current times the neuron's scale multiplier)"
    )
    return (
        f"hard WTA: of the neurons with v_j > v_threshold_j at a step, only the one with the largest {score} "
        "spikes (ties: lowest index); every one of them resets to v_reset = 0; nothing else is inhibited"
    )


READOUT_RULE = "vprsnn-hard-wta"
READOUT_RULE_VERSION = 2  # 2: the WTA runs within each group of group_size consecutive neurons (a module)
READABLE_RULE_VERSIONS = (1, 2)  # 1: one group of all neurons


def populations(source: Source) -> list[dict[str, Any]]:
    """One entry per module m of the lif node (a single network is one): the neurons [m n, (m + 1) n) of the one
    linear / lif pair, trained on the reference places [region start, region stop) (indices into
    metadata['reference_place_ids']), and their thresholds."""
    group = source.config.network.n_neurons  # one module's neurons
    regions = module_regions(len(source.reference_place_ids), source.config.train.module_size)
    thresholds = np.asarray(source.threshold if isinstance(source, FixedPointModel) else source.thresholds)
    ids = source.reference_place_ids
    return [
        {
            "name": f"module_{m}",
            "neurons": [m * group, (m + 1) * group],
            "places": [int(start), int(stop)],
            "place_ids": [int(ids[start]), int(ids[stop - 1])] if stop > start else [],
            "v_threshold_range": [float(f(thresholds[m * group : (m + 1) * group])) for f in (np.min, np.max)],
        }
        for m, (start, stop) in enumerate(regions.tolist())
    ]


def readout_rule(source: Source) -> dict[str, Any]:
    """The hard WTA as a machine-readable rule over the lif node's WTA-off spikes (stored as JSON)."""
    if not source.config.network.wta:
        return {"name": "none", "version": READOUT_RULE_VERSION, "output": "the lif node's spikes as they are"}
    group = wta_group(source.config, len(source.calibration))  # every neuron, or one module's (wta_scope)
    return {
        "name": READOUT_RULE,
        "version": READOUT_RULE_VERSION,
        "group_size": group,
        "scope": source.config.network.wta_scope,
        "groups": len(source.calibration) // group,
        "candidates": "the lif node's spikes at a step (every neuron with v_j > v_threshold_j; all of them reset)",
        "score": "I_j * wta_score_multiplier_j, with I_j = sum_i linear.weight[j, i] s_i[t] the linear node's output",
        "groups_rule": "the neurons form groups of group_size consecutive indices (group g: [g group_size, "
        "(g + 1) group_size): the whole ensemble for scope 'ensemble', one module each for scope 'module'); the "
        "rule runs in every group independently",
        "winner": "in each group, the candidate with the largest score; ties: the lowest index",
        "output": "at most one spike per group per step: the group winner's",
        "arithmetic": "integer (exact) for kind fixed-point; float32 for kind float",
        "function": "vprsnn_export.targets.nir_target.apply_readout_rule",
    }


def graph_metadata(source: Source, source_sha256: str | None, inhibition: float | None, dt: float) -> dict[str, Any]:
    """Human-readable facts plus the source's full JSON header for an exact rebuild."""
    cfg = source.config
    beta = effective_beta(source)
    if isinstance(source, FixedPointModel):
        kind, header, recorded_sha256 = "fixed-point", source.header(), source.source_sha256
        multipliers = source.scale_multiplier.astype(np.int64)
    else:
        kind, header, recorded_sha256 = "float", checkpoint_header(source), "unknown"
        multipliers = np.ones(source.weights.shape[1], dtype=np.int64)
    meta: dict[str, Any] = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "package_version": __version__,
        "kind": kind,
        "header_json": json.dumps(header, sort_keys=True),
        "source_sha256": source_sha256 or recorded_sha256,
        "dt": dt,
        "beta": beta,
        "tau_rule": "tau = dt / (1 - beta), r = 1 / (1 - beta): forward Euler at dt gives v <- beta v + I",
        "other_dt": "a consumer stepping at dt' computes v <- (1 - k (1 - beta)) v + k I with k = dt'/dt (Euler)",
        "timesteps": cfg.encoder.timesteps,
        "encoder": f"s_i[t] ~ Bernoulli(clip({cfg.encoder.rate_scale} * pixel_i, 0, 1)), t = 0..{cfg.encoder.timesteps - 1}",
        "seed": cfg.seed,
        "encoder_contract": json.dumps(encoder_contract(cfg), sort_keys=True),
        "decision": json.dumps(
            decision_rule("the W+Prob distribution of the output counts (wprob_rule)"), sort_keys=True
        ),
        "wprob_rule": WPROB_RULE,
        "state": "v = 0 at the start of every presentation"
        if cfg.network.state_isolation
        else "v carried across presentations",
        "spike_rule": "spike when v > v_threshold, checked after the update of the same step",
        "reset": "v <- v_reset = 0 for every neuron over threshold, whether or not it wins the WTA",
        "wta": "on" if cfg.network.wta else "off",
        "wta_rule": wta_rule(source),
        "readout_rule": json.dumps(readout_rule(source), sort_keys=True),
        "modules": module_count(len(source.reference_place_ids), cfg.train.module_size),
        "wta_group": wta_group(cfg, len(source.calibration)),
        "populations": json.dumps(populations(source), sort_keys=True),
        "consumer_settings": json.dumps(consumer_settings(dt), sort_keys=True),
        "integer_semantics": json.dumps(integer_semantics(source), sort_keys=True),
        "float_consumers": json.dumps(float_consumers(source), sort_keys=True),
        "wta_node": (
            "none (left out on request)"
            if inhibition is None
            else "wta: recurrent Linear W[j, i] = -wta_inhibition * v_threshold_j (i != j): "
            "lateral inhibition, one step late; not the WTA rule itself"
        ),
        "wta_inhibition": 0.0 if inhibition is None else float(inhibition),
        "wta_score_multiplier": multipliers,
        "calibration": source.calibration.astype(np.int64),
        "reference_place_ids": source.reference_place_ids.astype(np.int64),
    }
    if isinstance(source, FixedPointModel):
        meta.update(
            bits=source.bits,
            scale_exponent=source.scale_exponent,
            decay_dv=source.decay_dv,
            voltage_shift=source.voltage_shift,
            voltage_bits=source.voltage_bits,
            units=(
                "linear.weight = q_ij (float weight ~ q_ij m_j 2**scale_exponent); lif.v_threshold = theta_int_j; "
                "v is the 24-bit Loihi voltage / 2**voltage_shift; the integer decay rounds toward zero and "
                "the voltage saturates at +-(2**23 - 1), which a float consumer does not do"
            ),
            float_calibration=source.float_calibration.astype(np.int64),
        )
    return meta


def inhibition_weights(thresholds: np.ndarray, strength: float) -> np.ndarray:
    """W_inh[j, i] = -strength * v_threshold_j for i != j, 0 on the diagonal (float32).

    Each other neuron's spike at step t - 1 lowers neuron j's input at step t by ``strength``
    of j's own threshold, so the strength means the same in float and mantissa units.
    """
    off_diagonal = 1.0 - np.eye(thresholds.shape[0])
    return (-strength * np.asarray(thresholds, dtype=np.float64)[:, None] * off_diagonal).astype(np.float32)


def build_graph(
    source: Source,
    *,
    source_sha256: str | None = None,
    wta_inhibition: float = WTA_INHIBITION,
    wta_node: bool = False,
    dt: float = DT_SECONDS,
):
    """The ``nir.NIRGraph`` of a float checkpoint or a fixed-point model (module docstring): input -> linear ->
    lif -> output with the hard WTA as the metadata's readout rule (:func:`apply_readout_rule`), plus the
    recurrent ``wta`` Linear when ``wta_node``."""
    import nir

    if wta_inhibition < 0 or not np.isfinite(wta_inhibition):
        raise InvalidValueError(f"wta_inhibition must be a finite value >= 0, got {wta_inhibition}")
    if not (math.isfinite(real_number("dt", dt)) and 0 < dt <= 1e6):
        raise InvalidValueError(f"dt must be a time step in (0, 1e6] seconds, got {dt!r:.40}")
    if isinstance(source, FixedPointModel):
        validate(source, Path("<fixed-point model>"))
        weight = source.weight_mantissa.T.astype(np.float32)
        thresholds = source.threshold.astype(np.float64)
    elif isinstance(source, Checkpoint):
        validate_checkpoint(source)
        weight = np.ascontiguousarray(source.weights.T.astype(np.float32))
        thresholds = source.thresholds.astype(np.float32)
    else:
        raise InvalidValueError(f"cannot export a {type(source).__name__} to NIR")
    n_out, n_in = weight.shape
    nodes = {
        "input": nir.Input(input_type=np.array([n_in])),
        "linear": nir.Linear(weight=weight),
        "lif": lif_node(effective_beta(source), thresholds, dt),
        "output": nir.Output(output_type=np.array([n_out])),
    }
    if wta_node:
        nodes["wta"] = nir.Linear(weight=inhibition_weights(thresholds, wta_inhibition))
    metadata = graph_metadata(source, source_sha256, wta_inhibition if wta_node else None, dt)
    return nir.NIRGraph(nodes=nodes, edges=list(EDGES if wta_node else PLAIN_EDGES), metadata=metadata)


def write_nir(source: Source, path: str | Path, **options: Any) -> Path:
    """:func:`build_graph` (``options``: its keywords) serialised by ``nir.write`` in memory, written atomically."""
    import nir

    path = require_path("path", path)
    buffer = io.BytesIO()
    nir.write(buffer, build_graph(source, **options))
    return atomic_write_bytes(path, buffer.getvalue())


def consumer_settings(dt: float) -> dict[str, Any]:
    """How to load the file in each NIR consumer so that it computes the WTA-off network (stored as JSON).

    Each consumer's WTA-off raster then goes through :func:`apply_readout_rule`. Norse 1.1 integrates
    v' <- v' + g (v_leak - v' + I) with g = dt/tau and no r, i.e. v' = g v (1 - beta = g): a threshold
    g_j v_threshold_j, with g_j computed as Norse does (float32 dt * (1 / tau_j)), gives the network's
    spikes; in particular v' = g I right after a reset equals it exactly when I = v_threshold (a tie,
    no spike), which scaling the weights by r instead would get wrong by rounding. SpikingJelly 2.0
    fires at v >= v_threshold: the next float32 above v_threshold makes that v > v_threshold.
    """
    return {
        "nirtorch": {"dt": dt, "load": "NIR's LIF stepped by forward Euler at dt; nothing else to set"},
        "snntorch": {
            "load": "snntorch.import_nir.import_from_nir(graph) (dt 1e-4 built in)",
            "needs": "one v_threshold for all neurons (quantize --fold-thresholds)",
        },
        "norse": {
            "dt": dt,
            "v_threshold": "times_norse_gain",
            "load": "Norse 1.1 ignores lif.r, so its voltage is (dt/tau) v: set lif.v_threshold to "
            "g * v_threshold with g = dt * (1 / tau) in torch.float32 (as Norse computes it), then "
            "norse.torch.from_nir(graph, dt=dt)",
        },
        "spikingjelly": {
            "dt": dt,
            "v_threshold": "next_float32_above",
            "load": "SpikingJelly 2.0 fires at v >= v_threshold: set lif.v_threshold to "
            "numpy.nextafter(numpy.float32(v_threshold), numpy.float32(inf)), then "
            "spikingjelly.activation_based.nir_exchange.import_from_nir(graph, dt=dt)",
            "needs": "one v_threshold for all neurons (quantize --fold-thresholds)",
        },
        "then": "apply_readout_rule(graph, input spikes, the consumer's spikes) for the network's raster",
    }


def sparse_currents(inputs: torch.Tensor, matrix: torch.Tensor) -> torch.Tensor:
    """``I = s W^T`` for input spike rows ``s`` (rows, inputs) and ``matrix = W^T`` (inputs, neurons), summing only
    the rows of ``matrix`` whose input spikes: ``I_r = sum_{i : s_ri != 0} s_ri W^T_i`` (one embedding bag)."""
    rows, columns = inputs.nonzero(as_tuple=True)
    offsets = torch.zeros(inputs.shape[0], dtype=torch.int64)
    offsets[1:] = torch.bincount(rows, minlength=inputs.shape[0]).cumsum(0)[:-1]
    values = inputs[rows, columns].to(matrix.dtype)
    weights = None if bool((values == 1).all()) else values
    return torch.nn.functional.embedding_bag(columns, matrix, offsets, mode="sum", per_sample_weights=weights)


def apply_readout_rule(graph, spikes: torch.Tensor, candidates: torch.Tensor) -> torch.Tensor:
    """The network's exact raster from any consumer's WTA-off spikes, by the rule in the graph's metadata.

    ``spikes`` (N, T, inputs) are the input spike trains, ``candidates`` (N, T, neurons) the
    consumer's output of the portable graph (every neuron over threshold). Per step:

        score_j = I_j m_j,  I = W s[t]   (W: the linear node's weight, m: wta_score_multiplier)
        winner  = argmax_{j in candidates of group g} score_j   (ties: lowest j), for every group g

    The rule runs within every group of ``group_size`` consecutive neurons (one module of an
    ensemble; version 1 rules: one group of all neurons). Returns (N, T, neurons) bool with at
    most one spike per group per step. A graph whose rule is ``none`` (WTA off) returns the
    candidates unchanged.
    """
    meta = graph.metadata
    rule = parse_json(str(meta.get("readout_rule", "{}")), "readout_rule")
    if rule.get("name") == "none":
        return candidates.to(torch.bool)
    if rule.get("name") != READOUT_RULE or int(rule.get("version", -1)) not in READABLE_RULE_VERSIONS:
        raise InvalidValueError(f"unknown readout rule {rule.get('name')!r} v{rule.get('version')!r} in the graph")
    weight = np.asarray(graph.nodes["linear"].weight)
    group = int(rule.get("group_size", weight.shape[0]))
    if group < 1 or weight.shape[0] % group:
        raise InvalidValueError(f"the readout rule's group_size {group} does not divide {weight.shape[0]} neurons")
    flat = spikes.reshape(-1, spikes.shape[-1])
    grouped = candidates.reshape(flat.shape[0], -1, group).to(torch.bool)
    # A group with one candidate spikes it, one with none is silent: scores are needed only where two or more
    # compete, so only those steps' currents are computed (input spikes are sparse, contests rare).
    contested = grouped.view(torch.uint8).sum(dim=2, dtype=torch.int32) >= 2
    steps = contested.any(dim=1).nonzero().flatten()
    winner = grouped.to(torch.uint8).argmax(dim=2)  # the only candidate where there is one
    if steps.numel():
        fixed = str(meta["kind"]) == "fixed-point"
        dtype = torch.float64 if fixed else torch.float32  # float64 sums of integer weights are exact below 2**53
        matrix = torch.as_tensor(np.ascontiguousarray(weight.T), dtype=dtype)
        if fixed:
            multipliers = torch.as_tensor(np.asarray(meta["wta_score_multiplier"]), dtype=torch.int64)
        for chunk in steps.split(4096):
            competing = grouped[chunk].reshape(chunk.numel(), -1)
            if fixed:  # exact in any order: the sparse product touches only the few inputs that spike
                score = sparse_currents(flat[chunk], matrix).round().to(torch.int64) * multipliers
                masked = torch.where(competing, score, torch.iinfo(torch.int64).min)
            else:  # float32: the dense product's own summation order, as the float network computes it
                masked = torch.where(competing, flat[chunk].to(dtype) @ matrix, -torch.inf)
            best = masked.reshape(chunk.numel(), -1, group).argmax(dim=2)  # torch's first maximum: the lowest index
            winner[chunk] = torch.where(contested[chunk], best, winner[chunk])
    raster = torch.zeros(grouped.shape, dtype=torch.bool).scatter_(2, winner.unsqueeze(2), True)
    raster &= grouped.any(dim=2, keepdim=True)
    return raster.reshape(candidates.shape)
