"""The velocity estimators' registry: how a velocity is estimated from the query stream (paper Sec. V).

Each :class:`VelocityEstimator` wraps one search of :mod:`readout.aggregation` behind one signature; the CLI's
``--velocity-estimate`` and ``SequenceOptions.velocity_estimate`` choose among :data:`VELOCITY_ESTIMATES` and share one
default, :data:`DEFAULT_VELOCITY_ESTIMATE` (``smooth``, the CLI's default before the two were one). Adding one is a
function and one ``VELOCITY_ESTIMATES.register`` line (docs/architecture.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Final, Protocol

import numpy as np

from vprsnn_export.registry import Registry

from .aggregation import estimate_velocity, smooth_velocity, track_velocity


class SequenceOptions(Protocol):
    """What an estimator reads of :class:`vprsnn_export.readout.sequence.SequenceOptions` (a protocol, so that
    the options' module, which validates against this registry, is not imported back)."""

    @property
    def rule(self) -> str: ...
    @property
    def velocity_span(self) -> int: ...
    @property
    def velocity_length(self) -> int | None: ...
    @property
    def velocity_memory(self) -> int: ...
    @property
    def velocity_lag(self) -> int | None: ...


#: estimate(prob (Q, places), k, candidates, frame_positions, options: SequenceOptions)
#: -> (velocity (Q,), aggregated (Q, places))
EstimateFunction = Callable[
    [np.ndarray, int, np.ndarray, "np.ndarray | None", "SequenceOptions"], tuple[np.ndarray, np.ndarray]
]

#: stream(k, options) -> (trajectory length, span, memory) of the causal tracker that gives the same velocity
#: one frame at a time (:meth:`vprsnn_export.readout.scoring.Readout.push`)
StreamSettings = Callable[[int, "SequenceOptions"], tuple[int, int, int]]


@dataclass(frozen=True)
class VelocityEstimator:
    """One way to estimate the velocity; ``description`` is its help text; ``stream`` its causal form (None:
    it waits for later frames, so a stream cannot use it)."""

    name: str
    estimate: EstimateFunction
    description: str
    stream: StreamSettings | None = None


def _smooth(p: np.ndarray, k: int, c: np.ndarray, t: np.ndarray | None, o: SequenceOptions) -> tuple:
    return smooth_velocity(
        p, k, c, o.velocity_span, o.rule, t, lag=o.velocity_lag, length=o.velocity_length, memory=o.velocity_memory
    )


def _track(p: np.ndarray, k: int, c: np.ndarray, t: np.ndarray | None, o: SequenceOptions) -> tuple:
    return track_velocity(p, k, c, o.velocity_span, o.rule, t, length=o.velocity_length, memory=o.velocity_memory)


def _window(p: np.ndarray, k: int, c: np.ndarray, t: np.ndarray | None, o: SequenceOptions) -> tuple:
    return estimate_velocity(p, k, c, o.rule, t)


VELOCITY_ESTIMATES: Registry[VelocityEstimator] = Registry("velocity estimate")
_WAITS = (
    "smooth the velocity over the recent and the next --velocity-lag windows (each decision waits for that many frames)"
)
VELOCITY_ESTIMATES.register(VelocityEstimator("smooth", _smooth, _WAITS))
VELOCITY_ESTIMATES.register(
    VelocityEstimator(
        "track",
        _track,
        "track it over the recent windows only (causal)",
        lambda k, o: (o.velocity_length or 2 * k, o.velocity_span, o.velocity_memory),
    )
)
_ALONE = "choose it per window on its own (the older, noisier search)"
VELOCITY_ESTIMATES.register(VelocityEstimator("window", _window, _ALONE, lambda k, o: (k, 1, 0)))

#: The one default of the library and the CLI.
DEFAULT_VELOCITY_ESTIMATE: Final[str] = "smooth"


def causal_estimates() -> tuple[str, ...]:
    """The estimates a stream can use (those with a causal form), in registration order."""
    return tuple(e.name for e in VELOCITY_ESTIMATES.values() if e.stream is not None)


__all__ = ["DEFAULT_VELOCITY_ESTIMATE", "VELOCITY_ESTIMATES", "VelocityEstimator", "causal_estimates"]
