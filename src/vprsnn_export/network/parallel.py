"""How the compiled kernels share a call among Python threads, and the tiles of neurons they run.

Each kernel call is serial and releases the GIL: ``threads`` > 1 runs parts of a call (contiguous
slices of modules, :func:`module_slices`; whole WTA groups of neurons or presentations,
:func:`run_parts`) on a pool of Python threads (:func:`run_threads`). numba's threading layer is
never launched (once launched, its OpenMP workers slowed torch's training loop sevenfold here).
Inference runs the neurons in tiles of whole WTA groups (:func:`neuron_tile`): a tile's weights,
copied contiguous, stay in cache across presentations.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import numpy as np

from ..errors import InvalidValueError

TILE_NEURONS = 400  # neurons per tile of the kernels: one module of the default size
#: The bytes of presentations' currents (T x tile float32 each) a wide tile sums before their steps, in column
#: blocks of :data:`TILE_NEURONS`: a tile wider than that (one WTA over a whole
#: ensemble: 27,000 neurons on a 27k lean route) then reads each block's weights from cache for all of them,
#: not every row of the tile from memory for every presentation (1.8x at 27,000 neurons, 2 threads: bench_wide_group.py)
CURRENT_BYTES = 32 * 2**20


def neuron_tile(n_neurons: int, group: int) -> int:
    """Whole WTA groups, about :data:`TILE_NEURONS` neurons (at least one group, at most all)."""
    return min(n_neurons, group * max(1, TILE_NEURONS // group))


def current_blocks(timesteps: int, tile: int, presentations: int) -> tuple[int, int]:
    """(column, chunk) of a kernel's tile (:func:`~.dynamics_kernel._float_kernel`): a tile of at most
    ``TILE_NEURONS`` is one block, its currents one presentation at a time (its weights stay in cache across
    presentations); a wider one is cut into blocks of
    ``TILE_NEURONS`` and the currents of :data:`CURRENT_BYTES` of presentations are summed at once. A lone
    presentation (a localiser's frame) has none to share a block's weights with: one block (7 % faster at 27k)."""
    if tile <= TILE_NEURONS or presentations < 2:
        return tile, 1
    return TILE_NEURONS, max(1, min(presentations, CURRENT_BYTES // (4 * timesteps * tile)))


def run_parts(
    n_presentations: int, n_neurons: int, group: int, threads: int, isolation: bool
) -> list[tuple[slice, int, int]]:
    """How ``threads`` threads share a run: (presentations, start, stop) per thread.

    Neurons in whole WTA groups when there are enough groups (any isolation), else presentations
    (state isolation only: otherwise presentations are one stream and run in order).
    """
    groups = n_neurons // group
    if threads > 1 and groups >= threads:
        return [(slice(0, n_presentations), p.start * group, p.stop * group) for p in module_slices(groups, threads)]
    if threads > 1 and isolation and n_presentations > 1:
        return [(part, 0, n_neurons) for part in module_slices(n_presentations, threads)]
    return [(slice(0, n_presentations), 0, n_neurons)]


Result = TypeVar("Result")


def run_threads(tasks: Sequence[Callable[[], Result]], workers: int | None = None) -> list[Result]:
    """The tasks' results in order, on ``workers`` Python threads (None: one per task) when there are several; an
    interrupt or SIGTERM waits for the tasks in flight only (the queued ones never start)."""
    threads = len(tasks) if workers is None else workers
    if threads < 2 or len(tasks) == 1:
        return [task() for task in tasks]
    pool = ThreadPoolExecutor(max_workers=threads)
    try:
        return list(pool.map(lambda task: task(), tasks))
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def check_group(n_neurons: int, group: int | None) -> int:
    """The WTA group size: ``n_neurons`` for ``None``; ValueError unless it divides ``n_neurons``."""
    size = n_neurons if group is None else int(group)
    if size < 1 or n_neurons % size:
        raise InvalidValueError(f"group: WTA groups of {size} neurons do not divide {n_neurons} neurons")
    return size


def module_slices(n_modules: int, parts: int) -> list[slice]:
    """At most ``parts`` contiguous, non-empty, nearly equal slices of range(n_modules)."""
    bounds = np.linspace(0, n_modules, max(1, min(parts, n_modules)) + 1).round().astype(int)
    return [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True) if b > a]
