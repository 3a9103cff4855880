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


def log_term(probability: np.ndarray, eps: float) -> np.ndarray:
    r"""The product rule's term of one frame: :math:`\log(\tilde P_m(l) + \varepsilon)`."""
    return np.log(probability + eps)


def softmax_finish(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""The product rule's end: :math:`\hat P_j(l) = e^{A_j(l)} / \sum_{l'} e^{A_j(l')}` (a stable softmax), and
    the score :math:`\max_l A_j(l)`, the best joint log-likelihood."""
    peak = a.max(axis=1, keepdims=True)
    e = np.exp(a - peak)
    return e / e.sum(axis=1, keepdims=True), peak[:, 0]


def softmax_finish_filled(
    values: np.ndarray, where: np.ndarray, fill: float, n_places: int
) -> tuple[np.ndarray, np.ndarray]:
    r""":func:`softmax_finish` of the row that is ``fill`` at every place but ``where`` (``values`` there), the same
    numbers, with :math:`e^{\text{fill} - \text{peak}}` taken once: a search window's aggregate is the term of 0
    summed at all but a few places (:func:`~vprsnn_export.readout.aggregation.aggregate_newest_on_support`)."""
    peak = np.array([values.max(initial=fill)])
    e = np.full(n_places, np.exp(fill - peak)[0])
    e[where] = np.exp(values - peak[0])
    return (e / e.sum(keepdims=True))[None], peak


def probability_term(probability: np.ndarray, eps: float) -> np.ndarray:
    r"""The sum rule's term of one frame: :math:`\tilde P_m(l)` itself."""
    return probability


def l1_finish(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""The sum rule's end: :math:`\hat P_j(l) = A_j(l) / \sum_{l'} A_j(l')` (the uniform distribution where
    :math:`A_j` is 0 everywhere), and the score :math:`\max_l A_j(l)`, the best summed probability."""
    total = a.sum(axis=1, keepdims=True)
    out = a / np.where(total > 0, total, 1.0)
    out[total[:, 0] <= 0, :] = 1.0 / a.shape[1]
    return out, a.max(axis=1)


@dataclass(frozen=True)
class AggregationRule:
    r"""How a shifted window is combined: each frame's ``term`` summed over the window, then ``finish``ed.

    .. math:: A_j(l) = \sum_{m \in W_j} \text{term}(\tilde P_m(l)), \quad
              (\hat P_j, \text{score}_j) = \text{finish}(A_j)

    Product: term :math:`\log(\cdot + \varepsilon)`, finish a softmax; sum: term the probability, finish an L1
    normalisation. A frame shifted by whole places is its term shifted (``term(0)`` beyond the map), so a window of
    k frames needs each frame's term once (:func:`~vprsnn_export.readout.aggregation.aggregate`)."""

    name: str
    term: Callable[[np.ndarray, float], np.ndarray]
    finish: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
    description: str
    #: ``finish`` of a row that is one value at all but some places (values, places, value, length), when the rule
    #: has a quicker form than ``finish`` over the whole row; None: ``finish`` itself
    finish_filled: Callable[[np.ndarray, np.ndarray, float, int], tuple[np.ndarray, np.ndarray]] | None = None

    def zero_term(self, eps: float) -> float:
        """The term of a probability 0: a place beyond the map, or outside a frame's support."""
        return float(self.term(np.zeros(1), eps)[0])

    def finish_row(self, values: np.ndarray, where: np.ndarray, fill: float, n_places: int) -> np.ndarray:
        """The finished distribution (1, places) of the row that is ``fill`` but ``values`` at ``where``."""
        if self.finish_filled is not None:
            return self.finish_filled(values, where, fill, n_places)[0]
        row = np.full(n_places, fill)
        row[where] = values
        return self.finish(row[None])[0]

    def combine(self, shifted: np.ndarray, valid: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray]:
        """``shifted`` (Q, k, places), ``valid`` (Q, k) -> (aggregated distribution (Q, places), window score (Q,));
        a frame before the stream's start (not valid) adds nothing."""
        return self.finish((self.term(shifted, eps) * valid[:, :, None]).sum(axis=1))


#: The aggregation rules (the CLI's --rule; the first is the default).
RULES: Registry[AggregationRule] = Registry("aggregation rule")
RULES.register(
    AggregationRule(
        "product",
        log_term,
        softmax_finish,
        "product of the frames' probabilities (softmax of log sums)",
        softmax_finish_filled,
    )
)
RULES.register(AggregationRule("sum", probability_term, l1_finish, "sum of the frames' probabilities"))
#: The default rule of the library and the CLI: the first registered.
DEFAULT_RULE: Final[str] = RULES.names()[0]


__all__ = ["DEFAULT_RULE", "RULES", "AggregationRule"]
