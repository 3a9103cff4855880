"""How a query traversal's decisions are judged, built once per traversal: :class:`Truth`.

Two kinds answer the same questions (which predictions are correct, which reference places are true for each
query, whether the model's places can match the queries at all, how a result names it):

* :class:`MatchWindow`: index-aligned place ids (a manifest, the synthetic route, equal-length folders); a
  prediction within ``places`` ids of the query's own id is correct;
* :class:`GroundTruth`: a data set's ground-truth file, ``matrix[r, q]`` True when reference place id ``r``
  matches query place id ``q`` (a query may match several references, or none).

A new kind is one more subclass; no reader asks which kind it holds. A :class:`Query` is one query traversal as
every evaluation takes it: its frames, their place ids and its truth.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from vprsnn_export.arguments import check_place_ids, require_integer, require_type
from vprsnn_export.errors import InvalidValueError

MAX_WINDOW = 1_000_000  # places either side: beyond any route


class Truth(ABC):
    """The judge of one query traversal's decisions (:class:`MatchWindow` or :class:`GroundTruth`)."""

    source: str = ""  # the ground-truth file ("": index-aligned place ids)

    @property
    @abstractmethod
    def label(self) -> str:
        """How decisions were judged, in the words every result states (``match window: N`` or ``ground truth: FILE``)."""

    @property
    def match_window(self) -> int:
        """The match window a result records beside ``source`` (0 with a ground truth)."""
        return 0

    @abstractmethod
    def matches(self, predicted: np.ndarray, queries: np.ndarray) -> np.ndarray:
        """Whether each predicted place id (never a no-match) is a correct match of the query's place id."""

    def correct(self, predicted_ids: np.ma.MaskedArray | np.ndarray, query_place_ids: np.ndarray) -> np.ndarray:
        """Per query: the prediction names a true place (a masked entry, a no-match, is never correct).

        .. math:: \\mathrm{correct}_q = \\mathrm{matched}_q \\wedge \\mathrm{true}(\\mathrm{pred}_q, q)
        """
        matched = ~np.ma.getmaskarray(predicted_ids)
        predicted = np.asarray(np.ma.filled(predicted_ids, 0), dtype=np.int64)
        return matched & self.matches(predicted, np.asarray(query_place_ids, dtype=np.int64))

    @abstractmethod
    def true_places(self, query_place_ids: np.ndarray) -> tuple[np.ndarray, ...]:
        """Each query's true reference place ids (int64 arrays)."""

    @abstractmethod
    def first_true(self, reference_place_ids: np.ndarray, query_place_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For each query, the index into ``reference_place_ids`` of its first true reference, and whether it has one

        .. math:: \\hat r_q = \\min \\{l : \\mathrm{true}(\\mathrm{ref}_l, q)\\} \\quad (0 \\text{ where there is none})
        """

    def check_overlap(self, reference_place_ids: np.ndarray, query_place_ids: np.ndarray) -> None:
        """InvalidValueError when no query can match a reference place: every decision would be wrong by
        construction (the model was trained on other places)."""
        reference = np.asarray(reference_place_ids, dtype=np.int64)
        queries = np.asarray(query_place_ids, dtype=np.int64)
        if reference.size and queries.size and not self.first_true(reference, queries)[1].any():
            raise InvalidValueError(self.no_overlap(reference, queries))

    @abstractmethod
    def no_overlap(self, reference: np.ndarray, queries: np.ndarray) -> str:
        """Why no query can match a reference place, for :meth:`check_overlap`'s error."""


@dataclass(frozen=True)
class MatchWindow(Truth):
    """Index-aligned place ids: a prediction within ``places`` ids of the query's own is correct (0: exact)."""

    places: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "places", require_integer("match window", self.places, 0, MAX_WINDOW))

    @property
    def label(self) -> str:
        return f"match window: {self.places}"

    @property
    def match_window(self) -> int:
        return int(self.places)

    def matches(self, predicted: np.ndarray, queries: np.ndarray) -> np.ndarray:
        """.. math:: |\\mathrm{pred}_q - q| \\le \\mathrm{places}"""
        return np.abs(predicted - queries) <= self.places

    def true_places(self, query_place_ids: np.ndarray) -> tuple[np.ndarray, ...]:
        return tuple(np.asarray(query_place_ids, dtype=np.int64)[:, None])

    def first_true(self, reference_place_ids: np.ndarray, query_place_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The nearest reference within the window: its own place first (the lowest index among equals)."""
        reference = np.asarray(reference_place_ids, dtype=np.int64)
        queries = np.asarray(query_place_ids, dtype=np.int64)
        if reference.size == 0:
            return np.zeros(len(queries), dtype=np.int64), np.zeros(len(queries), dtype=bool)
        order = np.argsort(reference, kind="stable")
        ordered = reference[order]
        after = np.clip(np.searchsorted(ordered, queries), 0, len(ordered) - 1)
        before = np.clip(after - 1, 0, len(ordered) - 1)
        nearer = np.abs(ordered[before] - queries) < np.abs(ordered[after] - queries)
        position = np.where(nearer, before, after)
        return order[position], np.abs(ordered[position] - queries) <= self.places

    def no_overlap(self, reference: np.ndarray, queries: np.ndarray) -> str:
        return (
            f"none of the {queries.size} query places ({queries.min()}..{queries.max()}) is among the model's "
            f"{reference.size} reference places ({reference.min()}..{reference.max()}): select the places it was "
            "trained on (--places / --subset)"
        )


@dataclass(frozen=True, eq=False)
class GroundTruth(Truth):
    """A data set's ground truth in place ids: ``matrix[r, q]`` True when reference place id ``r`` correctly
    matches query place id ``q``; ``source`` names its file."""

    matrix: np.ndarray  # bool (reference place ids, query place ids)
    source: str = ""

    def __post_init__(self) -> None:
        matrix = np.asarray(self.matrix)
        if matrix.ndim != 2 or matrix.dtype != np.bool_:
            raise InvalidValueError(f"a ground truth is a 2-D boolean matrix, got {matrix.dtype} {matrix.shape}")
        require_type("source", self.source, str)
        object.__setattr__(self, "matrix", matrix)

    @property
    def label(self) -> str:
        return f"ground truth: {self.source}"

    def check_queries(self, queries: np.ndarray) -> None:
        """InvalidValueError when a query place id lies outside the matrix's columns."""
        n_query = self.matrix.shape[1]
        if queries.size and (queries.min() < 0 or queries.max() >= n_query):
            raise InvalidValueError(f"query place ids outside the ground truth's 0..{n_query - 1} ({self.source})")

    def matches(self, predicted: np.ndarray, queries: np.ndarray) -> np.ndarray:
        """.. math:: \\mathrm{GT}[\\mathrm{pred}_q, q] \\quad (\\text{a predicted id outside the matrix: wrong})"""
        self.check_queries(queries)
        inside = (predicted >= 0) & (predicted < self.matrix.shape[0])
        return inside & self.matrix[np.where(inside, predicted, 0), queries]

    def true_places(self, query_place_ids: np.ndarray) -> tuple[np.ndarray, ...]:
        """``{r : GT[r, q]}`` per query, ascending."""
        ids = np.asarray(query_place_ids, dtype=np.int64)
        queries, places = np.nonzero(self.matrix[:, ids].T)  # row-major: queries ascending, places within each
        return tuple(np.split(places.astype(np.int64), np.cumsum(np.bincount(queries, minlength=len(ids)))[:-1]))

    def first_true(self, reference_place_ids: np.ndarray, query_place_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Reference ids outside the matrix match nothing."""
        reference = np.asarray(reference_place_ids, dtype=np.int64)
        queries = np.asarray(query_place_ids, dtype=np.int64)
        self.check_queries(queries)
        matches = np.zeros((len(reference), len(queries)), dtype=bool)
        inside = (reference >= 0) & (reference < self.matrix.shape[0])
        matches[inside] = self.matrix[np.ix_(reference[inside], queries)]
        return np.asarray(matches.argmax(axis=0)), np.asarray(matches.any(axis=0))

    def no_overlap(self, reference: np.ndarray, queries: np.ndarray) -> str:
        return (
            f"none of the {queries.size} queries matches one of the model's {reference.size} reference places "
            f"by the ground truth {self.source}: select the places it was trained on (--places / --subset)"
        )


def window(places: int | None = 0) -> MatchWindow:
    """The truth of index-aligned data, ``places`` ids either side (None: exact)."""
    return MatchWindow(int(places or 0))


#: The truth of index-aligned data judged by exact place ids (the default of every evaluation).
EXACT = MatchWindow(0)


@dataclass(frozen=True, eq=False)
class Query:
    """One query traversal as every evaluation takes it: its name, its preprocessed frames (N, inputs) in stream
    order, their place ids and the truth that judges them (built once: :meth:`~vprsnn_export.data.dataset.Dataset.query`)."""

    traversal: str
    images: np.ndarray
    place_ids: np.ndarray
    truth: Truth = EXACT

    def __post_init__(self) -> None:
        require_type("traversal", self.traversal, str)
        require_type("truth", self.truth, Truth)
        ids = check_place_ids(self.place_ids, "place_ids")
        if np.ndim(self.images) != 2 or len(self.images) != len(ids):
            raise InvalidValueError(
                f"images must be (queries, inputs) with one row per place id ({len(ids)}), got {np.shape(self.images)}"
            )
        object.__setattr__(self, "place_ids", ids)
