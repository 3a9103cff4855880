"""The integer semantics a NIR file states, and what a float NIR consumer computes from it (machine-readable).

Two metadata entries (JSON) of every NIR file:

``integer_semantics``: the arithmetic the network performs, which Lava/Loihi and the float
path read the same way:

    fixed point:  V <- trunc_toward_zero(V * (4096 - dv) / 4096) + (a << s);  V <- clip(V, -(2**23 - 1), 2**23 - 1)
                  spike when V > theta << s;  V <- 0 for every neuron over threshold
                  (V: the 24-bit Loihi voltage; the file's v is V / 2**s, s = voltage_shift)
    float:        v <- beta v + I in float32;  spike when v > theta;  v <- 0

``float_consumers``: whether a float consumer running NIR's LIF/IF (``v <- beta v + I``)
reproduces it exactly, why, and the decision tolerance the export and verify gates apply:

* non-leaky fixed point (dv = 0, beta = 1, an IF node): v <- v + a on integers, exact in
  float32 while |v| < 2**24 (and in float64 below 2**53) -> exact; tolerance 100 %.
* memoryless fixed point (dv = 4096, beta = 0): v <- a, exact in any float type -> exact.
* leaky fixed point (0 < dv < 4096): V (4096 - dv) / 4096 is an integer only when 4096 / g
  divides V (g = gcd(4096 - dv, 4096)), so the truncation drops a fraction in [0, 1) Loihi
  units at almost every step; the integer voltage falls below the float one by up to
  2**-s / (1 - beta) of the file's units (0.31 at beta = 3891/4096, s = 6), and a crossing
  closer than that moves. No voltage scaling removes it: a larger s (more fractional bits)
  shrinks the bound but never to zero, since after k decays without input an integer V
  stays equal to beta**k V only if (4096 / g)**k divides V, which fails for every V != 0
  once k > 24 / log2(4096 / g). -> not exact; tolerance :data:`LEAKY_DECISION_TOLERANCE`
  (measured, docs/targets.md section 1.4).
* float file: the consumer's float32 (or float64) current sums run in another order than the
  float network's -> not exact; same tolerance.
"""

from __future__ import annotations

from typing import Any

from vprsnn_export.export.model import DECAY_BITS, FixedPointModel
from vprsnn_export.io.checkpoint import Checkpoint

#: NIR lateral inhibition per other spike, in thresholds (the wta node): measured best for a metadata-blind consumer
#: on the Nordland subset (docs/targets.md).
WTA_INHIBITION = 1.0
#: Decision agreement the gates require of a file whose consumers are stated exact.
EXACT_DECISION_TOLERANCE = 1.0
#: Decision agreement the gates require of the other files: the worst single-network cell of the
#: measured matrix on the default network (2-bit folded, 98 %) with room for another route's queries;
#: an ensemble at 2 bits measured 84-95 % and fails it (docs/targets.md section 1.4).
LEAKY_DECISION_TOLERANCE = 0.95


def integer_semantics(source: Checkpoint | FixedPointModel) -> dict[str, Any]:
    """The update, spike, reset and saturation rules of the network, as numbers a reader can apply."""
    reset = {"value": 0, "who": "every neuron over threshold, whether or not it wins the WTA"}
    if isinstance(source, FixedPointModel):
        limit = source.voltage_limit
        return {
            "arithmetic": "integer",
            "decay": {
                "multiplier": (1 << DECAY_BITS) - source.decay_dv,
                "divisor": 1 << DECAY_BITS,
                "rounding": "toward_zero",
                "equation": "V <- trunc_toward_zero(V * multiplier / divisor) + (a << voltage_shift)",
            },
            "saturation": {"min": -limit, "max": limit, "units": "Loihi voltage (mantissa units * 2**voltage_shift)"},
            "voltage_shift": source.voltage_shift,
            "spike": "V > (theta_int << voltage_shift), after the update of the same step",
            "reset": reset,
        }
    return {
        "arithmetic": "float32",
        "decay": {"beta": float(source.config.network.beta), "rounding": "nearest (float32)"},
        "equation": "v <- beta v + I",
        "spike": "v > theta (after the update of the same step)",
        "reset": reset,
    }


def float_consumers(source: Checkpoint | FixedPointModel) -> dict[str, Any]:
    """Whether a float consumer of NIR's LIF/IF computes this file exactly, the cause, and the gate's tolerance."""
    if isinstance(source, FixedPointModel) and source.decay_dv in (0, 1 << DECAY_BITS):
        non_leaky = source.decay_dv == 0
        return {
            "mode": "non-leaky (IF)" if non_leaky else "memoryless (beta = 0)",
            "exact": True,
            "cause": (
                f"v <- v + a on integers: float32 is exact while |v| < 2**24 (theta_int <= {int(source.threshold.max())}"
                " plus one step's current)"
                if non_leaky
                else "v <- a: no decay to round"
            ),
            "decision_tolerance": EXACT_DECISION_TOLERANCE,
        }
    if isinstance(source, FixedPointModel):
        beta = ((1 << DECAY_BITS) - source.decay_dv) / (1 << DECAY_BITS)
        cause = (
            f"the integer decay V <- trunc_toward_zero(V * {(1 << DECAY_BITS) - source.decay_dv} / {1 << DECAY_BITS})"
            " rounds toward zero, which NIR's LIF (v <- beta v + I) cannot express: the integer voltage falls below "
            f"the float one by up to {2.0**-source.voltage_shift / (1 - beta):.2f} of the file's units and crossings "
            "that close move"
        )
        mode = "leaky (decay rounds toward zero)"
    else:
        cause = "the consumer sums the currents in another order (float32 rounding) than the float network"
        mode = "float"
    return {"mode": mode, "exact": False, "cause": cause, "decision_tolerance": LEAKY_DECISION_TOLERANCE}
