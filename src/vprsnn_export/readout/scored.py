"""What a readout decided for a query traversal, decided once: :class:`Scored`, one :class:`Column` per readout.

A column is one (strategy, k): every query's predicted reference index, its place id, its confidence, whether it
is correct by the traversal's :class:`~vprsnn_export.data.truth.Truth`, and the metric row of those decisions.
Every reader (the metric rows, the PR curves, the paired statistics, the agreement between two networks, the
per-module rows, the per-query predictions, an operating point) takes the columns; none decides again.
A new readout column is one more entry of :func:`readout_columns`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from vprsnn_export.data.truth import Truth

from .metrics import MetricRow, metric_row, pr_curve, pr_metrics, predicted_place_ids
from .regions import ModuleAccuracy, module_accuracy
from .strategies import SEQUENCE_STRATEGY, STRATEGIES, decide


@dataclass(frozen=True, eq=False)
class Column:
    """One readout's decisions: per query the predicted reference index (-1: no match), its place id (masked for
    a no-match), the confidence, correct or not (None: unlabelled queries), and the metric row (None likewise)."""

    strategy: str
    k: int
    index: np.ndarray  # (Q,) int64
    place_id: np.ma.MaskedArray  # (Q,) int64
    confidence: np.ndarray  # (Q,) float64
    correct: np.ndarray | None  # (Q,) bool
    row: MetricRow | None

    @property
    def decisions(self) -> tuple[np.ndarray, np.ndarray]:
        """(correct, confidence) per query: what the PR metrics and the paired statistics take."""
        assert self.correct is not None, "unlabelled queries have no correct decisions"
        return self.correct, self.confidence

    def curve(self) -> tuple[np.ndarray, np.ndarray]:
        """The exact PR operating points (precision, recall) of these decisions (:func:`~.metrics.pr_curve`)."""
        return pr_curve(*self.decisions)[:2]


def judged_column(
    strategy: str,
    k: int,
    index: np.ndarray,
    confidence: np.ndarray,
    reference_place_ids: np.ndarray,
    query_place_ids: np.ndarray | None,
    truth: Truth | None,
) -> Column:
    """The column of decisions already made (predicted index per query, -1: no match; confidence), judged by
    ``truth``: each query's place id, correctness and the metric row of them all (index and confidence as
    :func:`~.strategies.decide` gives them)."""
    ids = predicted_place_ids(index, reference_place_ids)
    if query_place_ids is None or truth is None:
        return Column(strategy, k, index, ids, confidence, None, None)
    correct = truth.correct(ids, query_place_ids)
    return Column(
        strategy, k, index, ids, confidence, correct, metric_row(strategy, k, pr_metrics(correct, confidence))
    )


def readout_columns(
    scores: Mapping[str, np.ndarray], aggregates: Mapping[int, np.ndarray]
) -> list[tuple[str, int, np.ndarray]]:
    """(strategy, k, scores) of every readout: each strategy at k=1, :data:`SEQUENCE_STRATEGY` at each k > 1."""
    return [(s, 1, scores[s]) for s in STRATEGIES] + [
        (SEQUENCE_STRATEGY, k, aggregates[k]) for k in sorted(aggregates) if k > 1
    ]


@dataclass(frozen=True, eq=False)
class Scored:
    """A query traversal read out by one network: its columns, the k=1 scores and the aggregates they came from."""

    columns: tuple[Column, ...]
    scores: Mapping[str, np.ndarray]  # every strategy's k=1 scores (Q, places); {} when read out in blocks
    aggregates: Mapping[int, np.ndarray]  # the sequence strategy aggregated at every k (k=1 included); {} likewise
    reference_place_ids: np.ndarray
    query_place_ids: np.ndarray | None
    truth: Truth | None

    @classmethod
    def of(
        cls,
        scores: Mapping[str, np.ndarray],
        aggregates: Mapping[int, np.ndarray],
        reference_place_ids: np.ndarray,
        query_place_ids: np.ndarray | None,
        truth: Truth | None,
    ) -> Scored:
        """Every readout column of these scores, each decided once and judged by ``truth`` (None: unlabelled):

        .. math:: \\hat l_q = \\arg\\max_l \\mathrm{Score}_{ql}, \\quad \\mathrm{correct}_q = \\mathrm{truth}(\\mathrm{id}(\\hat l_q), q)
        """
        columns = tuple(
            judged_column(s, k, *decide(m, s), reference_place_ids, query_place_ids, truth)
            for s, k, m in readout_columns(scores, aggregates)
        )
        return cls(columns, scores, aggregates, np.asarray(reference_place_ids), query_place_ids, truth)

    @property
    def rows(self) -> list[MetricRow]:
        """The metric rows, in column order (every strategy at k=1, then the sequence strategy at each k > 1)."""
        return [c.row for c in self.columns if c.row is not None]

    @property
    def ks(self) -> tuple[int, ...]:
        """The sequence lengths read out (1 included)."""
        return tuple(sorted({1} | {c.k for c in self.columns}))

    def column(self, strategy: str, k: int = 1) -> Column:
        """The column of ``strategy`` at ``k`` (KeyError when it was not read out)."""
        for column in self.columns:
            if (column.strategy, column.k) == (strategy, k):
                return column
        raise KeyError((strategy, k))

    def decisions(self) -> dict[tuple[str, int], tuple[np.ndarray, np.ndarray]]:
        """Per (strategy, k): each query's (correct, confidence)."""
        return {(c.strategy, c.k): c.decisions for c in self.columns}

    def regions(self, regions: np.ndarray, k: int = 1) -> list[ModuleAccuracy]:
        """Per module: accuracy and in-region share of the sequence strategy's decisions at ``k`` on the queries
        whose true place (by the same truth) lies in its region (:func:`~.regions.module_accuracy`)."""
        assert self.query_place_ids is not None and self.truth is not None, "unlabelled queries have no regions"
        column = self.column(SEQUENCE_STRATEGY, k)
        true_index, known = self.truth.first_true(self.reference_place_ids, self.query_place_ids)
        return module_accuracy(column.index, column.decisions[0], self.reference_place_ids, regions, true_index, known)
