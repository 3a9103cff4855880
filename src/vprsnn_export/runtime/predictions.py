"""Per-query results: what each strategy and sequence length decided for every query (`evaluate --predictions`).

For query ``q`` (in stream order), strategy ``s`` and sequence length ``k``:

.. math:: \\hat l_q = \\arg\\max_l \\mathrm{Score}^{(s, k)}_{ql}, \\quad c_q = \\text{confidence of } \\hat l_q,
          \\quad \\text{correct}_q = |\\mathrm{id}(\\hat l_q) - \\text{truth}_q| \\le \\text{match window}

(with a data set's ground-truth file, ``correct_q = GT[id(l_q), q]``: ``readout.metrics.MatchTruth``), with the
very scores the metric rows are computed from (``runtime.evaluation``: every strategy at k = 1, W+Prob
aggregated at each k > 1), so the accuracy of a (strategy, k) column of :class:`Predictions` equals that row's
accuracy.

The ``truth`` column holds the query's true place ids: its own place id on index-aligned data, and with a
ground truth the reference place ids the file names for it (``{r : GT[r, q]}``, several or none: then empty,
and ``note`` says why), never the frame index. JSON lines write it as a list, CSV as ids separated by spaces.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.io.fileio import atomic_write_text
from vprsnn_export.readout.metrics import MatchTruth, Tolerance, is_correct, predicted_place_ids
from vprsnn_export.readout.scoring import Readout, columns
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.readout.strategies import SEQUENCE_STRATEGY, decide

FORMATS = (".csv", ".jsonl")
#: The columns of a row (:meth:`Predictions.rows`), in this order.
FIELDS = ("query", "truth", "strategy", "k", "place_id", "confidence", "correct", "note")


@dataclass(frozen=True)
class Decided:
    """One (strategy, k) column: the decided place id per query (-1: no match), its confidence, correct or not."""

    strategy: str
    k: int
    place_id: np.ndarray  # (Q,) int64, -1 for a no-match
    confidence: np.ndarray  # (Q,) float64
    correct: np.ndarray | None  # (Q,) bool; None without ground truth


@dataclass(frozen=True)
class Predictions:
    """Every query's decision under every strategy and k; ``truth`` None when the queries are unlabelled."""

    truth: tuple[np.ndarray, ...] | None  # per query, the int64 place ids a correct decision names
    decided: tuple[Decided, ...]
    source: str = ""  # the ground-truth file the truth comes from ("": the queries' own place ids)

    @property
    def n_queries(self) -> int:
        return len(self.decided[0].place_id) if self.decided else 0

    def column(self, strategy: str, k: int = 1) -> Decided:
        for entry in self.decided:
            if (entry.strategy, entry.k) == (strategy, k):
                return entry
        raise InvalidValueError(f"no predictions for {strategy} at k={k}")

    def rows(self) -> list[dict[str, Any]]:
        """Long format: one row per (query, strategy, k), queries in stream order."""
        no_place = f"the ground truth ({self.source}) names no reference place for this query"
        out = []
        for q in range(self.n_queries):
            for entry in self.decided:
                place = int(entry.place_id[q])
                truth = None if self.truth is None else [int(r) for r in self.truth[q]]
                correct = None if entry.correct is None else bool(entry.correct[q])
                decided = (entry.strategy, entry.k, None if place < 0 else place, float(entry.confidence[q]), correct)
                out.append(dict(zip(FIELDS, (q, truth, *decided, no_place if truth == [] else ""), strict=True)))
        return out

    def to_csv(self) -> str:
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=FIELDS, lineterminator="\n")
        writer.writeheader()
        for row in self.rows():
            truth = row["truth"]
            row["truth"] = None if truth is None else " ".join(map(str, truth))
            writer.writerow({k: "" if v is None else v for k, v in row.items()})
        return buffer.getvalue()

    def to_jsonl(self) -> str:
        return "".join(json.dumps(row) + "\n" for row in self.rows())

    def write(self, path: str | Path) -> Path:
        """Write as CSV or JSON lines, chosen by the suffix (.csv, .jsonl), atomically."""
        suffix = Path(path).suffix.lower()
        if suffix not in FORMATS:
            raise InvalidValueError(f"--predictions {path}: give a .csv or .jsonl file name")
        return atomic_write_text(path, self.to_csv() if suffix == ".csv" else self.to_jsonl())


def predictions(
    scores: Mapping[str, np.ndarray],
    reference_place_ids: np.ndarray,
    query_place_ids: np.ndarray | None,
    options: SequenceOptions,
) -> Predictions:
    """The decisions behind :meth:`vprsnn_export.readout.scoring.Readout.rows`, per query."""
    aggregates = {k: options.aggregate(scores[SEQUENCE_STRATEGY], k) for k in sorted(set(options.ks))}
    decided = []
    for strategy, k, matrix in columns(scores, aggregates):
        index, confidence = decide(matrix, strategy)
        ids = predicted_place_ids(index, reference_place_ids)
        correct = None if query_place_ids is None else is_correct(ids, query_place_ids, options.tolerance)
        decided.append(Decided(strategy, k, np.asarray(ids.filled(-1), dtype=np.int64), confidence, correct))
    if query_place_ids is None:
        return Predictions(truth=None, decided=tuple(decided))
    source = options.tolerance.source if isinstance(options.tolerance, MatchTruth) else ""
    return Predictions(true_places(query_place_ids, options.tolerance), tuple(decided), source)


def true_places(query_place_ids: np.ndarray, tolerance: Tolerance) -> tuple[np.ndarray, ...]:
    """Each query's true place ids: ``{r : GT[r, q]}`` with a ground truth, else ``{q}`` (its own place id).

    ``query_place_ids`` index the ground truth's columns (:func:`vprsnn_export.readout.metrics.truth_lookup`)."""
    ids = np.asarray(query_place_ids, dtype=np.int64)
    if not isinstance(tolerance, MatchTruth):
        return tuple(ids[:, None])
    queries, places = np.nonzero(tolerance.matrix[:, ids].T)  # row-major: queries ascending, places within each
    return tuple(np.split(places.astype(np.int64), np.cumsum(np.bincount(queries, minlength=len(ids)))[:-1]))


def network_predictions(
    network: Checkpoint | FixedPointModel,
    query_counts: np.ndarray,
    query_place_ids: np.ndarray | None,
    options: SequenceOptions,
) -> Predictions:
    """Per-query decisions from an evaluation's spike counts (``Evaluation.query_counts``), read out with
    the network's own calibration (an ensemble's with its region regularisation), like its metric rows."""
    scores = Readout.of(network.calibration, network.config, options).scores(query_counts)
    return predictions(scores, network.reference_place_ids, query_place_ids, options)
