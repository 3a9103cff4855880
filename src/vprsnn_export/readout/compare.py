"""Two readouts of the same queries compared, column by column: what `verify` asks of float and deployed.

Both sides are :class:`~.scored.Scored`; nothing here decides again.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .scored import Column, Scored
from .strategies import SEQUENCE_STRATEGY, STRATEGIES


def top1_agreement(a: Column, b: Column) -> float:
    """Fraction of queries with the same decision (the same place, or both no-match):
    :math:`\\frac{1}{Q} \\#\\{q : \\hat l^a_q = \\hat l^b_q\\}`."""
    return float(np.mean(a.index == b.index))


def tv_distance(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Total variation distance :math:`\\tfrac12 \\sum_l |p(l) - q(l)|` per row, in [0, 1]."""
    return 0.5 * np.abs(np.asarray(p, dtype=np.float64) - np.asarray(q, dtype=np.float64)).sum(axis=1)


def strategy_agreement(a: Scored, b: Scored) -> dict[str, float]:
    """Top-1 agreement of every strategy at k=1."""
    return {s: top1_agreement(a.column(s, 1), b.column(s, 1)) for s in STRATEGIES}


def sequence_agreement(a: Scored, b: Scored, ks: Sequence[int]) -> dict[int, float]:
    """Top-1 agreement of the sequence strategy at every k of ``ks``."""
    return {k: top1_agreement(a.column(SEQUENCE_STRATEGY, k), b.column(SEQUENCE_STRATEGY, k)) for k in sorted(ks)}


def sequence_distance(a: Scored, b: Scored) -> np.ndarray:
    """Per query, the total variation distance between the two sequence-strategy distributions at k=1."""
    return tv_distance(a.scores[SEQUENCE_STRATEGY], b.scores[SEQUENCE_STRATEGY])
