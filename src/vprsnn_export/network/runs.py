"""One result type for every implementation of the network, and the interface they share.

A *backend* is anything that presents spike trains (N, T, inputs) of 0/1 uint8 to the
network and reports what it did: the float reference (:class:`vprsnn_export.network.dynamics.FloatNetwork`),
the integer simulator and its reference stepper, onnxruntime on the exported graph, and the
exported files read back. They all return a :class:`SpikeRun`, so verification iterates over
backends instead of special-casing each one.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Protocol, runtime_checkable

import numpy as np
import torch
from tqdm import tqdm


@dataclass(frozen=True)
class SpikeRun:
    """The outcome of presenting N spike trains to one implementation of the network.

    ``counts`` is always there; the other fields are what the backend can observe
    (``None`` where it cannot, e.g. onnxruntime has no per-step candidate counts).
    """

    counts: torch.Tensor  # (N, neurons) int64 output spike counts
    candidates_per_step: torch.Tensor | None = None  # (N, T) int32 |C[t]|, the neurons over threshold
    raster: torch.Tensor | None = None  # (N, T, neurons) bool, when recorded
    final_voltage: torch.Tensor | None = None  # (N, neurons) V after each presentation's last step
    saturations: int = 0  # voltage clips to the largest representable voltage (integer backends)
    max_current: int = 0  # largest unshifted integer current a_j[t] seen (integer backends)
    wprob: np.ndarray | None = None  # (N, places) W+Prob distribution, from backends that compute the readout

    def head(self, n: int) -> SpikeRun:
        """The first n presentations (saturations and max_current are totals: kept as they are)."""
        return replace(
            self,
            counts=self.counts[:n],
            candidates_per_step=None if self.candidates_per_step is None else self.candidates_per_step[:n],
            raster=None if self.raster is None else self.raster[:n],
            final_voltage=None if self.final_voltage is None else self.final_voltage[:n],
            wprob=None if self.wprob is None else self.wprob[:n],
        )


def _joined(parts: list[torch.Tensor | None]) -> torch.Tensor | None:
    return None if any(p is None for p in parts) else torch.cat([p for p in parts if p is not None])


def run_in_chunks(
    run: Callable[[torch.Tensor], SpikeRun], spikes: torch.Tensor, *, chunk: int, progress: bool, desc: str
) -> SpikeRun:
    """``run`` on consecutive chunks of ``chunk`` presentations, with a progress bar on stderr when ``progress``.

    Only for state-isolated runs: each presentation starts from V = 0, so its spikes are a pure
    function of its own spike train and run(spikes) == concat(run(spikes[a:b]) for each chunk).
    Without ``progress`` it is one call, run(spikes). The bar is closed on any exception (``leave=False``),
    so no bar is left above the error line.
    """
    n = int(spikes.shape[0])
    if not progress or n <= chunk:
        return run(spikes)
    runs: list[SpikeRun] = []
    with tqdm(total=n, desc=desc, unit="presentation", file=sys.stderr, leave=False) as bar:
        for start in range(0, n, chunk):
            runs.append(run(spikes[start : start + chunk]))
            bar.update(min(chunk, n - start))
    return joined_runs(runs)


def joined_runs(runs: list[SpikeRun]) -> SpikeRun:
    """The runs of consecutive chunks of presentations as one run (saturations summed, max_current the largest)."""
    return SpikeRun(
        counts=torch.cat([r.counts for r in runs]),
        candidates_per_step=_joined([r.candidates_per_step for r in runs]),
        raster=_joined([r.raster for r in runs]),
        final_voltage=_joined([r.final_voltage for r in runs]),
        saturations=sum(r.saturations for r in runs),
        max_current=max(r.max_current for r in runs),
        wprob=None
        if any(r.wprob is None for r in runs)
        else np.concatenate([r.wprob for r in runs if r.wprob is not None]),
    )


@runtime_checkable
class Backend(Protocol):
    """An implementation of the network that runs spike trains: ``run(spikes, record=...) -> SpikeRun``."""

    @property
    def name(self) -> str:
        """A short human-readable name ("float", "integer simulator", "onnxruntime", ...)."""

    def run(self, spikes: torch.Tensor, *, record: bool = False) -> SpikeRun:
        """Present spikes (N, T, inputs) uint8; ``record`` asks for the raster and final voltages."""
