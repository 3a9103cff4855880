"""The assignment strategies' registry: scores, confidence and title of each (paper Sec. III-E).

A :class:`Strategy` turns the calibration counts S^R and the query counts S^Q into one row of place scores per query
(:mod:`readout.assignment` holds the equations) and says how a row becomes a decision (its no-match rule and
confidence). Every readout row, report table and per-strategy agreement iterates :data:`STRATEGIES` in registration
order; adding a strategy is one function and one ``STRATEGIES.register`` line (docs/architecture.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

import numpy as np

from vprsnn_export.arguments import real_number
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.registry import Registry

from .assignment import (
    NO_MATCH,
    distribution_decision,
    finite_matrix,
    share_decision,
    standard_scores,
    weighted_scores,
    wprob_distribution,
)

#: scores(sr (neurons, places), sq (queries, neurons), gamma) -> (queries, places): S^R (S~) and S^Q as float64 CSR
#: arrays (scipy.sparse, :func:`~.assignment.sparse_counts`), the scores dense
ScoreFunction = Callable[[np.ndarray, np.ndarray, float], np.ndarray]
#: decision(scores (queries, places)) -> (no-match mask (queries,), confidence (queries,))
DecisionFunction = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]

#: The strategy whose distribution is aggregated over a sequence (k > 1) and that the ONNX head computes.
SEQUENCE_STRATEGY: Final[str] = "wprob"


@dataclass(frozen=True)
class Strategy:
    """One neuron-assignment strategy.

    ``scores`` computes its rows from S^R and S^Q; ``decision`` gives the no-match mask and
    the confidence of a row (:func:`decide`). ``base``/``of_base`` (optional) derive the
    scores from another strategy's, which :func:`all_scores` computes once (W+Prob from
    the weighted scores). ``needs_gamma``: the involvement threshold gamma is required.
    """

    name: str
    title: str
    scores: ScoreFunction
    decision: DecisionFunction
    needs_gamma: bool = True
    base: str | None = None
    of_base: Callable[[np.ndarray], np.ndarray] | None = None


STRATEGIES: Registry[Strategy] = Registry("strategy")
STRATEGIES.register(
    Strategy("standard", "Standard", lambda sr, sq, gamma: standard_scores(sr, sq), share_decision, needs_gamma=False)
)
STRATEGIES.register(Strategy("weighted", "Weighted", weighted_scores, share_decision))
STRATEGIES.register(
    Strategy(
        "wprob",
        "W+Prob",
        lambda sr, sq, gamma: wprob_distribution(weighted_scores(sr, sq, gamma)),
        distribution_decision,
        base="weighted",
        of_base=wprob_distribution,
    )
)


def require_strategy(strategy: object) -> str:
    """``strategy`` when it is a name (str); InvalidValueError naming the argument otherwise (an array is unhashable)."""
    if not isinstance(strategy, str):
        raise InvalidValueError(
            f"strategy must be one of {', '.join(STRATEGIES.names())}, got {type(strategy).__name__}"
        )
    return strategy


def decide(scores: np.ndarray, strategy: str) -> tuple[np.ndarray, np.ndarray]:
    """Predicted place index and confidence per query.

    .. math:: \\hat l_q = \\arg\\max_l \\mathrm{Score}_{ql}, \\qquad
              c_q = \\begin{cases} \\max_l P(l \\mid Q_q) & \\text{wprob} \\\\
                     \\max_l \\mathrm{Score}_{ql} / \\sum_l \\mathrm{Score}_{ql} & \\text{standard, weighted}
                     \\end{cases}

    Returns ``(pred, confidence)``: ``pred`` int64 of shape ``(n_queries,)``, ties to the lowest place index;
    ``confidence`` float64. A query is a no-match (``pred == -1``, confidence 0) when the strategy's decision says so:
    all scores zero (standard / weighted) or a flat distribution, every entry equal (wprob; this covers the uniform
    distribution of :func:`~vprsnn_export.readout.assignment.wprob_distribution` and any flat aggregated distribution).
    For ``"wprob"`` pass the distribution (``wprob_distribution``, an aggregated distribution or
    ``baseline.sad_distribution``) as ``scores``. InvalidValueError for a strategy that is not registered.
    """
    entry = STRATEGIES.get(require_strategy(strategy))
    s = finite_matrix("scores", scores)
    pred = np.argmax(s, axis=1).astype(np.int64)
    no_match, conf = entry.decision(s)
    pred[no_match] = NO_MATCH
    conf[no_match] = 0.0
    return pred, conf


def strategy_scores(sr: np.ndarray, sq: np.ndarray, strategy: str, gamma: float | None = None) -> np.ndarray:
    """Scores (standard, weighted) or distribution (wprob), shape ``(n_queries, n_places)``.

    .. math::
        \\text{standard}: S^Q A, \\quad \\text{weighted}: \\text{eq. 9-11}, \\quad
        \\text{wprob}: \\text{eq. 12-13 applied to the weighted scores}

    ``gamma`` (eq. 9) is required for a strategy that ``needs_gamma`` (weighted, wprob)
    and ignored otherwise. Feed the result to :func:`decide` with the same ``strategy``.
    """
    entry = STRATEGIES.get(require_strategy(strategy))
    if gamma is None and entry.needs_gamma:
        raise InvalidValueError(f"strategy {strategy!r} needs the involvement threshold gamma")
    return entry.scores(sr, sq, 0.0 if gamma is None else real_number("gamma", gamma))


def all_scores(sr: np.ndarray, sq: np.ndarray, gamma: float) -> dict[str, np.ndarray]:
    """The scores of every registered strategy {name: (Q, places)}, a derived one from its base's scores."""
    scores: dict[str, np.ndarray] = {}
    for entry in STRATEGIES.values():
        if entry.base is not None and entry.of_base is not None and entry.base in scores:
            scores[entry.name] = entry.of_base(scores[entry.base])
        else:
            scores[entry.name] = entry.scores(sr, sq, gamma)
    return scores


__all__ = ["SEQUENCE_STRATEGY", "STRATEGIES", "Strategy", "all_scores", "decide", "strategy_scores"]
