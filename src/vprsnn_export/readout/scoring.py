"""The readout of one network: spike counts -> place scores -> decisions -> metric rows, batch or stream.

A :class:`Readout` is built once per network from its calibration S^R, the config's assignment
settings (gamma, an ensemble's module layout) and the :class:`~vprsnn_export.readout.sequence.SequenceOptions`.
``scores(counts)`` gives every registered strategy's k=1 scores of a batch, ``sequences`` the
:data:`~vprsnn_export.readout.strategies.SEQUENCE_STRATEGY` distribution aggregated at every k,
``score`` every readout column decided once (a :class:`~.scored.Scored`), ``rows`` its metric rows, and ``stream()`` a causal stream, one decision per frame.
"""

from __future__ import annotations

import sys

import numpy as np
from scipy import sparse
from tqdm import tqdm

from vprsnn_export.arguments import real_number, require_integer, require_type
from vprsnn_export.config import Config
from vprsnn_export.data.truth import Truth, window
from vprsnn_export.errors import InvalidValueError

from .assignment import sparse_counts, weighted_matrix, wprob_distribution
from .baseline import diagonal_sums, nearest_neighbour
from .metrics import MetricRow, metric_row, pr_metrics, predicted_place_ids
from .regions import ModuleLayout, calibrated_half, ensemble_layout, silenced_counts
from .scored import Scored, judged_column, readout_columns
from .sequence import SequenceOptions
from .strategies import SEQUENCE_STRATEGY, all_scores, decide
from .stream import ReadoutStream

#: Queries read out at once by :meth:`Readout.score_in_blocks` (its default).
READOUT_BLOCK = 1024


def decision_metrics(
    distribution: np.ndarray, strategy: str, reference_place_ids: np.ndarray, query_place_ids: np.ndarray, truth: Truth
) -> dict:
    """Accuracy, P@100R, R@100P, AUC-PR of one score matrix (Q, places) under ``strategy``, judged by ``truth``."""
    column = judged_column(strategy, 1, *decide(distribution, strategy), reference_place_ids, query_place_ids, truth)
    return pr_metrics(*column.decisions)


def baseline_rows(
    distribution: np.ndarray,
    reference_place_ids: np.ndarray,
    query_place_ids: np.ndarray,
    options: SequenceOptions,
    truth: Truth,
) -> list[MetricRow]:
    """The SAD baseline's distribution (Q, places) read out like W+Prob at every k of ``options`` (strategy "sad")."""
    rows = []
    for k in sorted(set(options.ks)):
        dist = options.aggregate(distribution, k)
        rows.append(metric_row("sad", k, decision_metrics(dist, "wprob", reference_place_ids, query_place_ids, truth)))
    return rows


def nearest_neighbour_rows(
    similarities: np.ndarray,
    name: str,
    reference_place_ids: np.ndarray,
    query_place_ids: np.ndarray,
    options: SequenceOptions,
    truth: Truth,
) -> list[MetricRow]:
    """A no-learning baseline read out as nearest neighbour at every k of ``options``: the best place, the margin
    between the best and second-best score as confidence, k frames summed along the diagonal at the given velocity
    (:func:`vprsnn_export.readout.baseline.diagonal_sums`). Rows with strategy ``name``."""
    decisions = nearest_neighbour_decisions(similarities, reference_place_ids, query_place_ids, options, truth)
    return [metric_row(name, k, pr_metrics(*decided)) for k, decided in decisions.items()]


def nearest_neighbour_decisions(
    similarities: np.ndarray,
    reference_place_ids: np.ndarray,
    query_place_ids: np.ndarray,
    options: SequenceOptions,
    truth: Truth,
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per k of ``options``: each query's (correct, confidence) under :func:`nearest_neighbour_rows`' rule."""
    out = {}
    for k in sorted(set(options.ks)):
        predicted, confidence = nearest_neighbour(diagonal_sums(similarities, k, options.velocity))
        out[k] = (truth.correct(predicted_place_ids(predicted, reference_place_ids), query_place_ids), confidence)
    return out


class Readout:
    """One network's readout: S^R, gamma, its module layout and the sequence options; it keeps no stream state
    (each :meth:`stream` does)."""

    def __init__(
        self,
        calibration: np.ndarray,
        gamma: float,
        options: SequenceOptions | None = None,
        modules: ModuleLayout | None = None,
    ) -> None:
        self.options = SequenceOptions() if options is None else options
        require_type("options", self.options, SequenceOptions)
        self.calibration = calibration
        self.gamma = real_number("gamma", gamma)
        self.modules = modules
        # the stream's S'' values, S^R column sums and stored entries per neuron
        self._prepared: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._calibrated: tuple[np.ndarray, np.ndarray] | None = None  # S~ and the silenced neurons

    @classmethod
    def of(cls, calibration: np.ndarray, config: Config, options: SequenceOptions | None = None) -> Readout:
        """The readout of a network trained with ``config``: gamma is its ``assignment.gamma`` (the one source),
        an ensemble's (``train.module_size`` > 0) module layout its regions and assignment settings."""
        require_type("config", config, Config)
        layout = ensemble_layout(config, np.shape(calibration)[1]) if np.ndim(calibration) == 2 else None
        return cls(calibration, config.assignment.gamma, options, layout)

    def scores(self, counts: np.ndarray) -> dict[str, np.ndarray]:
        """The k=1 scores of every registered strategy (``readout.strategies.STRATEGIES``), (Q, places) each.

        An ensemble's hyperactive neurons are silenced first (``readout.regions.regularise``: decided from S^R
        alone); the weighted scores are computed once and W+Prob derived from them (``all_scores``).
        """
        sr, silent = self.calibrated()
        sq = sparse_counts("counts", counts)
        if sq.shape[1] != sr.shape[0]:
            raise InvalidValueError(f"counts has {sq.shape[1]} neurons per query but the calibration {sr.shape[0]}")
        return all_scores(sr, silenced_counts(sq, silent), self.gamma)

    def calibrated(self) -> tuple[sparse.csr_array, np.ndarray]:
        """S~ (S^R for a single network; float64 CSR) and the silenced neurons (a mask), computed once: the
        query-independent half of every batch, block and frame read out (:func:`~.regions.calibrated_half`)."""
        if self._calibrated is None:
            self._calibrated = calibrated_half(self.calibration, self.modules)
        return self._calibrated

    def sequences(self, distribution: np.ndarray, frame_positions: np.ndarray | None = None) -> dict[int, np.ndarray]:
        """A distribution aggregated at every k of the options, k = 1 (itself) included: {k: (Q, places)}."""
        return {k: self.options.aggregate(distribution, k, frame_positions) for k in sorted(set(self.options.ks) | {1})}

    def judge(
        self, counts: np.ndarray, reference_place_ids: np.ndarray, query_place_ids: np.ndarray, truth: Truth | None
    ) -> Truth:
        """The truth the queries are judged by (None: the options' match window), once the arrays are checked: S^R
        (neurons, places) with one column per reference id and S^Q (queries, neurons) with one row per query id (else
        decisions would name the wrong places). InvalidValueError naming the argument that does not fit, or when a k
        exceeds the queries or no query can match a reference."""
        truth = window(self.options.tolerance) if truth is None else truth
        require_type("truth", truth, Truth)
        values = (self.calibration, counts, reference_place_ids, query_place_ids)
        names = ("calibration", "query_counts", "reference_place_ids", "query_place_ids")
        for name, value, ndim in zip(names, values, (2, 2, 1, 1), strict=True):
            if np.ndim(value) != ndim:
                raise InvalidValueError(f"{name} has shape {np.shape(value)}, expected {ndim}-D")
        (neurons, places), _, (n_references,), (n_queries,) = map(np.shape, values)
        if places != n_references:
            raise InvalidValueError(f"calibration covers {places} places but reference_place_ids names {n_references}")
        if np.shape(counts) != (n_queries, neurons):
            raise InvalidValueError(
                f"query_counts has shape {np.shape(counts)}, expected ({n_queries}, {neurons}): one row per query "
                "id, one column per neuron of the calibration"
            )
        if max(self.options.ks) > n_queries:  # no full window exists
            raise InvalidValueError(f"--k {max(self.options.ks)} exceeds the number of queries ({n_queries})")
        truth.check_overlap(reference_place_ids, query_place_ids)
        return truth

    def score(
        self,
        counts: np.ndarray,
        reference_place_ids: np.ndarray,
        query_place_ids: np.ndarray,
        truth: Truth | None = None,
        frame_positions: np.ndarray | None = None,
    ) -> Scored:
        """Every readout column of the queries, each decided once (:class:`~.scored.Scored`): every strategy at
        k=1, then :data:`SEQUENCE_STRATEGY` at each k > 1, judged by ``truth`` (None: the options' match window);
        InvalidValueError as :meth:`judge`.
        """
        truth = self.judge(counts, reference_place_ids, query_place_ids, truth)
        scores = self.scores(counts)
        aggregates = self.sequences(scores[SEQUENCE_STRATEGY], frame_positions)
        return Scored.of(scores, aggregates, reference_place_ids, query_place_ids, truth)

    def score_in_blocks(
        self,
        counts: np.ndarray,
        reference_place_ids: np.ndarray,
        query_place_ids: np.ndarray,
        truth: Truth | None = None,
        frame_positions: np.ndarray | None = None,
        block: int = READOUT_BLOCK,
        progress: bool = False,
    ) -> Scored:
        """:meth:`score` computed ``block`` queries at a time: no (queries x places) matrix is held, only each
        block's (block + k - 1 frames of history) and the decisions. Every column equals :meth:`score`'s bit for
        bit: a row of scores is a sparse product of that query's counts alone, and the k-frame windows reach back
        k - 1 frames, no further.

        .. math:: \\hat P_j = \\text{aggregate}(P_{j-k+1..j}) \\text{ needs rows } j-k+1..j \\text{ only}

        InvalidValueError as :meth:`score`, or with a velocity estimated from the stream (its windows reach
        ahead: read it out whole). ``progress``: a bar on stderr, queries read out and time left.
        """
        truth = self.judge(counts, reference_place_ids, query_place_ids, truth)
        block = require_integer("block", block, 1, 1 << 30)
        if self.options.velocity_candidates is not None:
            raise InvalidValueError("a velocity estimated from the stream looks ahead: read the queries out whole")
        n, history = len(query_place_ids), max(self.options.ks) - 1
        decided: dict[tuple[str, int], list[tuple[np.ndarray, np.ndarray]]] = {}
        with tqdm(total=n, desc="readout", unit="query", file=sys.stderr, leave=False, disable=not progress) as bar:
            for start in range(0, n, block):
                low, stop = max(0, start - history), min(n, start + block)
                positions = None if frame_positions is None else np.asarray(frame_positions)[low:stop]
                scores = self.scores(counts[low:stop])
                aggregates = self.sequences(scores[SEQUENCE_STRATEGY], positions)
                for strategy, k, matrix in readout_columns(scores, aggregates):
                    decided.setdefault((strategy, k), []).append(decide(matrix[start - low :], strategy))
                bar.update(stop - start)
        columns = []
        for (strategy, k), parts in decided.items():
            index, confidence = (np.concatenate(part) for part in zip(*parts, strict=True))
            columns.append(judged_column(strategy, k, index, confidence, reference_place_ids, query_place_ids, truth))
        return Scored(tuple(columns), {}, {}, np.asarray(reference_place_ids), query_place_ids, truth)

    def rows(
        self,
        counts: np.ndarray,
        reference_place_ids: np.ndarray,
        query_place_ids: np.ndarray,
        frame_positions: np.ndarray | None = None,
    ) -> list[MetricRow]:
        """The metric rows of :meth:`score` (by the options' match window)."""
        return self.score(counts, reference_place_ids, query_place_ids, None, frame_positions).rows

    def wprob(self, counts: np.ndarray, places: slice | None = None) -> np.ndarray:
        """W+Prob P(l | Q) of one frame's spike counts (neurons,), over the active neurons only.

        .. math:: \\mathrm{Score}_l = \\Big(\\sum_{i \\in A} S^Q_i S''_{il}\\Big)
                  \\frac{\\sum_{i \\in A} S^R_{il}}{\\sum_m S^R_{ml}}, \\quad
                  A = \\{i : S^Q_i > 0, \\text{not silent}\\}, \\quad P = \\text{wprob\\_distribution}(\\mathrm{Score})

        :meth:`scores`' W+Prob bit for bit (each place's terms summed in neuron order, ``np.bincount`` over the
        fired neurons' stored entries of S~ and S''), at the cost of the few neurons that fired rather than all of
        them; the query-independent half (S'' of eq. 9-11) is computed once. ``places``: the distribution over
        those places alone (a search window, 0 elsewhere; uniform when flat there), at the cost of the window.
        """
        sr, silent = self.calibrated()
        if self._prepared is None:  # S'' has S~'s entries (weighted_matrix keeps its structure): its values alone
            values = np.asarray(weighted_matrix(sr, self.gamma).data)
            self._prepared = (values, np.asarray(sr.sum(axis=0)).ravel(), np.diff(sr.indptr))
        weights, column_sum, stored = self._prepared
        sq = np.asarray(counts, dtype=np.float64)
        rows = np.flatnonzero((sq > 0) & ~silent)  # the active neurons
        first, last, _ = (slice(None) if places is None else places).indices(len(column_sum))
        starts, lengths = sr.indptr[rows], stored[rows]
        entries = np.repeat(starts - np.cumsum(lengths) + lengths, lengths) + np.arange(lengths.sum())
        place = sr.indices[entries]
        inside = (place >= first) & (place < last)
        entries, place = entries[inside], place[inside] - first
        summed = np.bincount(place, np.repeat(sq[rows], lengths)[inside] * weights[entries], last - first)
        fired = np.bincount(place, sr.data[entries], last - first)
        total = column_sum[first:last]
        penalty = np.where(total > 0, fired / np.where(total > 0, total, 1.0), 0.0)
        distribution = wprob_distribution((summed * penalty)[None])[0]
        if places is None or np.ptp(distribution) == 0:  # a flat window is no evidence: the uniform row, no match
            return distribution if places is None else np.full(len(column_sum), 1.0 / len(column_sum))
        row = np.zeros(len(column_sum))
        row[places] = distribution
        return row

    def stream(self) -> ReadoutStream:
        """A causal stream over this readout (the localiser's): one decision per frame pushed."""
        return ReadoutStream(self.wprob, self.options)


def readout_rows(
    calibration: np.ndarray,
    query_counts: np.ndarray,
    reference_place_ids: np.ndarray,
    query_place_ids: np.ndarray,
    options: SequenceOptions,
    config: Config,
    frame_positions: np.ndarray | None = None,
) -> list[MetricRow]:
    """The metric rows of one network trained with ``config`` (:meth:`Readout.of` ... :meth:`Readout.rows`)."""
    require_type("options", options, SequenceOptions)
    return Readout.of(calibration, config, options).rows(
        query_counts, reference_place_ids, query_place_ids, frame_positions
    )
