"""The Lava-convention description of a fixed-point model: the header and arrays of network.json / network.npz.

The mapping onto Lava's Dense + LIF and the WTA readout rule: :mod:`.loihi_target`'s docstring.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vprsnn_export.config import wta_group
from vprsnn_export.export.model import MODEL_ARRAYS, FixedPointModel, validate
from vprsnn_export.network.modules import module_regions
from vprsnn_export.targets.contract import decision_rule, encoder_contract, search_rule
from vprsnn_export.targets.loihi_budget import model_budgets
from vprsnn_export.targets.packing import describe_packing, pack_bits
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
OTHER_ARRAYS = ("exc_vth", "exc_bias_mant", "wta_score_multiplier", *MODEL_ARRAYS[3:])  # + the counts and place ids
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


def describe(model: FixedPointModel, *, source_sha256: str | None = None) -> LoihiDescription:
    """The Lava-convention description of ``model`` (see the module docstring)."""
    validate(model, Path("<fixed-point model>"))  # at most 8 bits: Lava's Dense holds them
    _, num_weight_bits, weight_exp = lava_weights(model)
    cfg = model.config
    n_in, n = model.n_inputs, model.n_neurons
    bound = int(model.weight_mantissa.astype(np.int64).sum(axis=0).max())
    arrays = {
        WEIGHTS_NAME: pack_bits(model.weight_mantissa.T, model.bits),
        "exc_vth": model.threshold.astype(np.int32),
        "exc_bias_mant": np.zeros(n, dtype=np.int16),
        "wta_score_multiplier": model.scale_multiplier.astype(np.int32),
        **{name: getattr(model, name).astype(np.int64) for name in MODEL_ARRAYS[3:]},  # the counts and place ids
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
                    "contract": encoder_contract(cfg),
                },
                "lava": f"lava.proc.io.source.RingBuffer(data=spikes ({n_in}, steps)) or any 1-bit spike source",
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
                "weights_storage": describe_packing(model.bits, (n, n_in), WEIGHT_LAYOUT)
                | {"holds": f"weight mantissas q_ji; Lava's Dense.weights = q << {LAVA_WEIGHT_BITS - model.bits}"},
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
        **(
            {"search": search_rule(cfg.train.module_size, len(model.reference_place_ids))}
            if cfg.train.module_size > 0
            else {}
        ),
        "resources": [asdict(budget) for budget in model_budgets(model)],
        "wta": {
            "enabled": cfg.network.wta,
            "group_size": wta_group(cfg, model.n_neurons),
            "scope": cfg.network.wta_scope,
            "rule": (
                "per step and per group of group_size consecutive exc neurons (the whole ensemble, or one module), "
                "of the neurons that spiked in Lava (all candidates, all reset), emit only the one with the largest "
                "a_j * m_j, ties to the lowest index; a_j = sum_i q_ij s_i of the same step"
            ),
            "score_multiplier": "wta_score_multiplier",
            "in_lava": "not expressible with Dense/LIF: a readout process that reads exc.s_out and the Dense "
            "activation and forwards one spike (WtaReadout in tests/targets/lava_conformance/run_lava.py; "
            "docs/targets.md section 2.4)",
        },
        "readout": {
            "calibration": "calibration (neurons, places): S^R of the deployed network",
            "reference_place_ids": "reference_place_ids",
            "place_ids": model.reference_place_ids.astype(int).tolist(),
            "gamma": cfg.assignment.gamma,
            "decision": decision_rule("the W+Prob distribution of the output counts (eq. 9-13)"),
        },
        "arithmetic": model.header()["arithmetic"],
        "fixed_point_model": model.header(),
        "netx": {"file": NETX_NAME, "vThMant": "one value" if uniform else "per neuron, shape (neurons,)"},
    }
    return LoihiDescription(header=header, arrays=arrays)


def module_populations(model: FixedPointModel) -> list[dict[str, Any]]:
    """One population per module: exc neurons [m n, (m + 1) n), its places, its own vth and current bound, what one
    module's Lava LIF would hold (``vth`` = exc_vth[neurons], ``dv`` the ensemble's, ``weights`` the rows
    [m n, (m + 1) n) of the connection's matrix)."""
    group = model.config.network.n_neurons
    regions = module_regions(len(model.reference_place_ids), model.config.train.module_size)
    vth, multipliers = model.threshold.reshape(-1, group), model.scale_multiplier.reshape(-1, group)  # per module
    sums = model.weight_mantissa.astype(np.int64).sum(axis=0).reshape(-1, group)
    return [
        {
            "name": f"exc_{m}",
            "kind": "LIF",
            "neurons": [m * group, (m + 1) * group],
            "places": [int(start), int(stop)],
            "vth_range": [int(vth[m].min()), int(vth[m].max())],
            "vth_uniform": bool(np.all(vth[m] == vth[m, 0])),
            "score_multiplier_range": [int(multipliers[m].min()), int(multipliers[m].max())],
            "current_bound": int(sums[m].max()),
            "synapses": int(model.n_inputs * group),
        }
        for m, (start, stop) in enumerate(regions.tolist())
    ]
