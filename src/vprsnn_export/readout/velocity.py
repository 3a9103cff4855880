"""The velocity estimators' registry: how a velocity is estimated from the query stream (paper Sec. V).

Each :class:`VelocityEstimator` wraps one search of :mod:`readout.aggregation` behind one
signature; the CLI's ``--velocity-estimate`` and ``ReadoutOptions.velocity_estimate``
choose among :data:`VELOCITY_ESTIMATES` and share one default,
:data:`DEFAULT_VELOCITY_ESTIMATE` (``smooth``, the CLI's default before the two were one).
Adding one is a function and one ``VELOCITY_ESTIMATES.register`` line (docs/architecture.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

import numpy as np

from vprsnn_export.registry import Registry

from .aggregation import estimate_velocity, smooth_velocity, track_velocity


@dataclass(frozen=True)
class VelocitySettings:
    """The search's settings: the aggregation rule, the windows summed (``span``), the frames per scored
    trajectory (``length``; None: the estimator's default), the frames whose mean is divided out
    (``memory``) and the frames each decision waits for (``lag``; None: the estimator's default)."""

    rule: str = "product"
    span: int = 10
    length: int | None = None
    memory: int = 50
    lag: int | None = None


#: estimate(prob (Q, places), k, candidates, frame_positions, settings) -> (velocity (Q,), aggregated (Q, places))
EstimateFunction = Callable[
    [np.ndarray, int, np.ndarray, "np.ndarray | None", VelocitySettings], tuple[np.ndarray, np.ndarray]
]


@dataclass(frozen=True)
class VelocityEstimator:
    """One way to estimate the velocity; ``description`` is its help text."""

    name: str
    estimate: EstimateFunction
    description: str


def _smooth(
    prob: np.ndarray, k: int, candidates: np.ndarray, positions: np.ndarray | None, settings: VelocitySettings
) -> tuple[np.ndarray, np.ndarray]:
    return smooth_velocity(
        prob,
        k,
        candidates,
        settings.span,
        settings.rule,
        positions,
        lag=settings.lag,
        length=settings.length,
        memory=settings.memory,
    )


def _track(
    prob: np.ndarray, k: int, candidates: np.ndarray, positions: np.ndarray | None, settings: VelocitySettings
) -> tuple[np.ndarray, np.ndarray]:
    return track_velocity(
        prob, k, candidates, settings.span, settings.rule, positions, length=settings.length, memory=settings.memory
    )


def _window(
    prob: np.ndarray, k: int, candidates: np.ndarray, positions: np.ndarray | None, settings: VelocitySettings
) -> tuple[np.ndarray, np.ndarray]:
    return estimate_velocity(prob, k, candidates, settings.rule, positions)


VELOCITY_ESTIMATES: Registry[VelocityEstimator] = Registry("velocity estimate")
VELOCITY_ESTIMATES.register(
    VelocityEstimator(
        "smooth",
        _smooth,
        "smooth the velocity over the recent and the next --velocity-lag windows (each decision waits for that "
        "many frames)",
    )
)
VELOCITY_ESTIMATES.register(VelocityEstimator("track", _track, "track it over the recent windows only (causal)"))
VELOCITY_ESTIMATES.register(
    VelocityEstimator("window", _window, "choose it per window on its own (the older, noisier search)")
)

#: The one default of the library and the CLI.
DEFAULT_VELOCITY_ESTIMATE: Final[str] = "smooth"


__all__ = [
    "DEFAULT_VELOCITY_ESTIMATE",
    "VELOCITY_ESTIMATES",
    "VelocityEstimator",
    "VelocitySettings",
]
