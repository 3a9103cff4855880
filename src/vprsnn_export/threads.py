"""CPU thread settings: every command takes ``--threads N`` and records the choice in its results.

torch (and OpenMP under it) defaults to one thread per core. On a small machine shared with
other work, that oversubscribes the cores and runs 10-20x slower than one thread, so the
default is one thread unless the user or ``OMP_NUM_THREADS`` says otherwise.
"""

from __future__ import annotations

import os

from .arguments import ascii_uint, require_integer
from .startup import InterruptsHeld

DEFAULT_THREADS = 1


def default_threads() -> int:
    """``OMP_NUM_THREADS`` when set to a positive integer, else :data:`DEFAULT_THREADS`."""
    count = ascii_uint(os.environ.get("OMP_NUM_THREADS", "").strip())
    return count if count is not None and count > 0 else DEFAULT_THREADS


def set_threads(threads: int | None = None) -> int:
    """Use ``threads`` CPU threads for torch (the default when None); returns the number in use."""
    count = require_integer("--threads", default_threads() if threads is None else threads, 1, 1024)
    with InterruptsHeld():  # a Ctrl-C inside torch's C++ start-up would abort: it arrives after the import
        import torch  # here, not at module top: the CLI imports this module before it can catch an interrupt

    torch.set_num_threads(count)
    return count
