"""Per-query results: what each strategy and sequence length decided for every query (`evaluate --predictions`).

For query ``q`` (in stream order), strategy ``s`` and sequence length ``k``:

.. math:: \\hat l_q = \\arg\\max_l \\mathrm{Score}^{(s, k)}_{ql}, \\quad c_q = \\text{confidence of } \\hat l_q,
          \\quad \\text{correct}_q = |\\mathrm{id}(\\hat l_q) - \\text{truth}_q| \\le \\text{match window}

(with a data set's ground-truth file, ``correct_q = GT[id(l_q), q]``: ``data.truth.GroundTruth``): the columns
of the readout's :class:`~vprsnn_export.readout.scored.Scored` the metric rows come from (every strategy at
k = 1, W+Prob aggregated at each k > 1), so the accuracy of a (strategy, k) column of :class:`Predictions`
equals that row's accuracy.

The ``truth`` column holds the query's true place ids: its own place id on index-aligned data, and with a
ground truth the reference place ids the file names for it (``{r : GT[r, q]}``, several or none: then empty,
and ``note`` says why), never the frame index. JSON lines write it as a list, CSV as ids separated by spaces.
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vprsnn_export.data.truth import Truth
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.io.fileio import atomic_write_text
from vprsnn_export.readout.scored import Scored
from vprsnn_export.readout.scoring import Readout
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.readout.strategies import SEQUENCE_STRATEGY

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
            row["truth"] = None if row["truth"] is None else " ".join(map(str, row["truth"]))
            writer.writerow({k: "" if v is None else v for k, v in row.items()})
        return buffer.getvalue()

    def write(self, path: str | Path) -> Path:
        """Write as CSV or JSON lines, chosen by the suffix (.csv, .jsonl), atomically."""
        if prediction_format(path) == ".csv":
            return atomic_write_text(path, self.to_csv())
        return atomic_write_text(path, "".join(json.dumps(row) + "\n" for row in self.rows()))


def prediction_format(path: str | Path) -> str:
    """A predictions file's format, its suffix (.csv or .jsonl); InvalidValueError for any other."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise InvalidValueError(f"--predictions {path}: give a .csv or .jsonl file name")
    return suffix


def predictions(scored: Scored) -> Predictions:
    """Every column of a readout, per query (:meth:`vprsnn_export.readout.scoring.Readout.score`): nothing is
    decided again, so a column's accuracy is its metric row's."""
    decided = tuple(
        Decided(c.strategy, c.k, np.asarray(c.place_id.filled(-1), dtype=np.int64), c.confidence, c.correct)
        for c in scored.columns
    )
    if scored.query_place_ids is None or scored.truth is None:
        return Predictions(truth=None, decided=decided)
    return Predictions(scored.truth.true_places(scored.query_place_ids), decided, scored.truth.source)


def network_predictions(
    network: Checkpoint | FixedPointModel,
    query_counts: np.ndarray,
    query_place_ids: np.ndarray | None,
    options: SequenceOptions,
    truth: Truth | None = None,
) -> Predictions:
    """Per-query decisions from an evaluation's spike counts (``Evaluation.query_counts``), read out with
    the network's own calibration (an ensemble's with its region regularisation), like its metric rows;
    ``truth`` judges them (None: the options' match window; unlabelled queries, None ids: no truth)."""
    readout = Readout.of(network.calibration, network.config, options)
    if query_place_ids is not None:
        return predictions(readout.score(query_counts, network.reference_place_ids, query_place_ids, truth))
    scores = readout.scores(query_counts)
    aggregates = readout.sequences(scores[SEQUENCE_STRATEGY])
    return predictions(Scored.of(scores, aggregates, network.reference_place_ids, None, None))
