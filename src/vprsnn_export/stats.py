"""Summary statistics over independently trained networks (seeds)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class MeanStd:
    """Mean and sample standard deviation (ddof=1; 0 for one value) of n values; None when n = 0."""

    mean: float | None
    std: float | None
    n: int

    def to_dict(self) -> dict[str, float | int | None]:
        return {"mean": self.mean, "std": self.std, "n": self.n}

    @classmethod
    def from_dict(cls, data: dict) -> MeanStd:
        return cls(data.get("mean"), data.get("std"), int(data.get("n", 0)))


def mean_std(values: Iterable[float | None]) -> MeanStd:
    """Mean and sample standard deviation of the values that are not None."""
    array = np.asarray([v for v in values if v is not None], dtype=np.float64)
    if not array.size:
        return MeanStd(None, None, 0)
    return MeanStd(float(array.mean()), float(array.std(ddof=1)) if array.size > 1 else 0.0, int(array.size))
