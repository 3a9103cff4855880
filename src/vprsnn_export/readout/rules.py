"""The aggregation rules' registry: how the shifted frames of a window are combined (paper Sec. V).

:func:`~vprsnn_export.readout.aggregation.aggregate` and every velocity search combine a window
with a registered :class:`AggregationRule`; the CLI's ``--rule`` lists them (the first is the
default). Adding one is a function and one ``RULES.register`` line (docs/architecture.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

import numpy as np

from vprsnn_export.registry import Registry


def product_rule(shifted: np.ndarray, valid: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """Softmax of the summed logs of the shifted window (``shifted`` (Q, k, places), ``valid`` (Q, k)).

    .. math:: A_j(l) = \\sum_m \\log(\\tilde P_m(l) + \\varepsilon), \\quad
              \\hat P_j(l) = e^{A_j(l)} / \\sum_{l'} e^{A_j(l')}

    Returns ``(hat P, max_l A_j(l))``: the score is the best joint log-likelihood.
    """
    logs = np.log(shifted + eps) * valid[:, :, None]
    a = logs.sum(axis=1)
    peak = a.max(axis=1, keepdims=True)
    e = np.exp(a - peak)
    return e / e.sum(axis=1, keepdims=True), peak[:, 0]


def sum_rule(shifted: np.ndarray, valid: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """L1 normalisation of the summed shifted window (a window that is 0 everywhere gives the uniform distribution).

    .. math:: A_j(l) = \\sum_m \\tilde P_m(l), \\quad \\hat P_j(l) = A_j(l) / \\sum_{l'} A_j(l')

    Returns ``(hat P, max_l A_j(l))``: the score is the best summed probability.
    """
    n_places = shifted.shape[2]
    a = shifted.sum(axis=1)
    total = a.sum(axis=1, keepdims=True)
    out = a / np.where(total > 0, total, 1.0)
    out[total[:, 0] <= 0, :] = 1.0 / n_places
    return out, a.max(axis=1)


@dataclass(frozen=True)
class AggregationRule:
    """How a shifted window is combined: ``combine(shifted (Q, k, places), valid (Q, k), eps)`` ->
    (aggregated distribution (Q, places), window score (Q,))."""

    name: str
    combine: Callable[[np.ndarray, np.ndarray, float], tuple[np.ndarray, np.ndarray]]
    description: str


#: The aggregation rules (the CLI's --rule; the first is the default).
RULES: Registry[AggregationRule] = Registry("aggregation rule")
RULES.register(AggregationRule("product", product_rule, "product of the frames' probabilities (softmax of log sums)"))
RULES.register(AggregationRule("sum", sum_rule, "sum of the frames' probabilities"))
#: The default rule of the library and the CLI: the first registered.
DEFAULT_RULE: Final[str] = RULES.names()[0]


__all__ = ["DEFAULT_RULE", "RULES", "AggregationRule", "product_rule", "sum_rule"]
