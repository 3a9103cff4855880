"""Summary statistics over independently trained networks (seeds)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from vprsnn_export.io.serial import JsonDataclass, json_options


@dataclass(frozen=True)
class MeanStd(JsonDataclass):
    """Mean and sample standard deviation (ddof=1; 0 for one value) of n values; None when n = 0."""

    mean: float | None = field(metadata=json_options(missing=None))
    std: float | None = field(metadata=json_options(missing=None))
    n: int = field(metadata=json_options(missing=0))


def mean_std(values: Iterable[float | None]) -> MeanStd:
    """Mean and sample standard deviation of the values that are not None."""
    array = np.asarray([v for v in values if v is not None], dtype=np.float64)
    if not array.size:
        return MeanStd(None, None, 0)
    return MeanStd(float(array.mean()), float(array.std(ddof=1)) if array.size > 1 else 0.0, int(array.size))
