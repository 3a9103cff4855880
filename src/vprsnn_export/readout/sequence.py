"""The sequence settings of every readout: k, the aggregation rule, the velocity or its estimate (paper Sec. V).

:class:`SequenceOptions` is the one place that declares them and their defaults; evaluate, simulate,
verify, localize and the CLI (``commands._common.add_sequence_options``, generated from its fields)
all read them from here, and it validates them once, when it is built.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields
from typing import Any, Final

import numpy as np

from vprsnn_export.errors import InvalidValueError

from .aggregation import DEFAULT_MEMORY, DEFAULT_SPAN, aggregate
from .rules import DEFAULT_RULE, RULES
from .velocity import DEFAULT_VELOCITY_ESTIMATE, VELOCITY_ESTIMATES

MAX_K: Final[int] = 10_000  # far above any meaningful sequence, low enough to fail before memory does
MAX_VELOCITY: Final[float] = 1000.0  # places per frame: beyond any camera rate along a route
MAX_SETTING: Final[int] = 100_000  # span, length, memory, lag
MAX_TOLERANCE: Final[int] = 1_000_000


#: The command-line flag of a field whose flag is not its name with dashes.
FLAGS: Final[dict[str, str]] = {"ks": "--k", "velocity_candidates": "--velocity-search", "tolerance": "--match-window"}


def option_flag(name: str) -> str:
    """The command-line flag of a SequenceOptions field (``commands._common.add_sequence_options``)."""
    return FLAGS.get(name, "--" + name.replace("_", "-"))


def _count(name: str, value: object, low: int, high: int, optional: bool = False) -> None:
    """InvalidValueError naming the field and its option unless ``value`` is an int in low..high (or None)."""
    if optional and value is None:
        return
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not low <= value <= high:
        raise InvalidValueError(f"{name} ({option_flag(name)}) expects an integer from {low} to {high}, got {value!r}")


def _velocities(values: object) -> tuple[float, ...]:
    """``values`` as floats when each is a finite real number of at most MAX_VELOCITY places per frame, else ()."""
    if not isinstance(values, (tuple, list)) or not all(
        isinstance(v, numbers.Real) and not isinstance(v, bool) for v in values
    ):
        return ()
    floats = tuple(float(v) for v in values)
    return floats if all(math.isfinite(v) and abs(v) <= MAX_VELOCITY for v in floats) else ()


@dataclass(frozen=True)
class SequenceOptions:
    """How decisions are aggregated over a sequence and scored (the CLI's sequence options, generated from these
    fields, their flags in :data:`FLAGS`).

    ``ks``: sequence lengths (W+Prob aggregated over k frames for k > 1); ``rule``: the aggregation rule
    (:data:`~vprsnn_export.readout.rules.RULES`); ``velocity``: places per frame, or with ``velocity_candidates`` the
    velocity estimated over that grid by the registered estimator ``velocity_estimate``
    (:data:`~vprsnn_export.readout.velocity.VELOCITY_ESTIMATES`) with its settings ``velocity_span`` (windows summed),
    ``velocity_length`` (frames per scored trajectory; None: the estimator's), ``velocity_memory`` (frames of stream
    contrast; 0: none) and ``velocity_lag`` (frames each "smooth" decision waits for; None: 2k - 1); ``tolerance``: on
    index-aligned data, a prediction within +-tolerance places of the query's own is correct (the default
    :class:`~vprsnn_export.data.truth.MatchWindow`). Gamma is not here: it is the config's ``assignment.gamma``.
    """

    ks: tuple[int, ...] = (1,)
    rule: str = DEFAULT_RULE
    velocity: float = 1.0
    velocity_candidates: tuple[float, ...] | None = None
    velocity_estimate: str = DEFAULT_VELOCITY_ESTIMATE
    velocity_span: int = DEFAULT_SPAN
    velocity_length: int | None = None
    velocity_memory: int = DEFAULT_MEMORY
    velocity_lag: int | None = None
    tolerance: int = 0  # the match window of index-aligned data (a ground-truth file judges by data.truth instead)

    def __post_init__(self) -> None:
        ks = tuple(self.ks) if isinstance(self.ks, (tuple, list)) else ()
        if not ks:
            raise InvalidValueError(f"ks (--k) expects integers from 1 to {MAX_K}, got {self.ks!r}")
        for k in ks:
            _count("ks", k, 1, MAX_K)
        object.__setattr__(self, "ks", tuple(int(k) for k in ks))
        RULES.get(self.rule)
        VELOCITY_ESTIMATES.get(self.velocity_estimate)
        v = self.velocity
        if not _velocities((v,)) or v == 0:
            raise InvalidValueError(
                f"velocity (--velocity) expects a non-zero number of places per frame from -{MAX_VELOCITY:g} to "
                f"{MAX_VELOCITY:g}, got {v!r}"
            )
        object.__setattr__(self, "velocity", float(v))
        if self.velocity_candidates is not None:
            values = _velocities(self.velocity_candidates)
            if not values:
                raise InvalidValueError(
                    f"velocity_candidates (--velocity-search) expects finite velocities from -{MAX_VELOCITY:g} to "
                    f"{MAX_VELOCITY:g}, at least one, got {self.velocity_candidates!r}"
                )
            object.__setattr__(self, "velocity_candidates", values)
        _count("velocity_span", self.velocity_span, 1, MAX_SETTING)
        _count("velocity_length", self.velocity_length, 1, MAX_SETTING, optional=True)
        _count("velocity_memory", self.velocity_memory, 0, MAX_SETTING)
        _count("velocity_lag", self.velocity_lag, 0, MAX_SETTING, optional=True)
        _count("tolerance", self.tolerance, 0, MAX_TOLERANCE)

    def aggregate(self, distribution: np.ndarray, k: int, frame_positions: np.ndarray | None = None) -> np.ndarray:
        """A distribution (Q, places) aggregated over k frames at ``velocity``, or with ``velocity_candidates`` at the
        velocity the registered estimator ``velocity_estimate`` chooses per frame (each one's description:
        :data:`~.velocity.VELOCITY_ESTIMATES`); ``k == 1`` returns ``distribution`` itself."""
        if k == 1:
            return distribution
        if self.velocity_candidates is not None:
            estimator = VELOCITY_ESTIMATES.get(self.velocity_estimate)
            return estimator.estimate(distribution, k, np.asarray(self.velocity_candidates), frame_positions, self)[1]
        return aggregate(distribution, k, self.velocity, rule=self.rule, frame_positions=frame_positions)

    def warning(self, query_place_ids: np.ndarray) -> str | None:
        """A warning when sequence aggregation is asked for on queries that are not consecutive places.

        Aggregation assumes the query stream is a traversal (consecutive place ids, in order, at the
        velocity); on a subset spread along the route its windows mix unrelated places.
        """
        steps = np.abs(np.diff(np.asarray(query_place_ids)))
        if max(self.ks) <= 1 or np.all(steps <= 2):  # fewer than two queries: no step
            return None
        return (
            f"sequence aggregation (k up to {max(self.ks)}) on queries that are not consecutive places: "
            f"{100 * float(np.mean(steps > 2)):.0f} % of successive queries are more than 2 places apart, so the "
            "k-frame windows mix unrelated places"
        )

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SequenceOptions:
        """The options of their JSON form (``dataclasses.asdict``); an older localize form (one ``k``) reads as ks=(k,)."""
        data = dict(data)
        if "k" in data:  # localize's form before SequenceOptions: one k, the velocity always tracked
            data["ks"] = (data.pop("k"),)
            data.setdefault("velocity_estimate", "track")
        unknown = sorted(set(data) - {f.name for f in fields(cls)})
        if unknown:
            raise InvalidValueError(f"unknown sequence options {', '.join(unknown)}")
        return cls(**data)  # lists become tuples when the options are built
