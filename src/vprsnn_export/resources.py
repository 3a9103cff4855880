"""Memory as a stated limit: the big arrays of a run are predicted and checked before they are allocated.

A run that would not fit stops with one :class:`~vprsnn_export.errors.InvalidValueError` naming the
predicted size, the limit and what sets it, instead of a numpy/torch allocation error or the
kernel's out-of-memory kill. The prediction counts the arrays that grow with the problem (bytes):

    input spikes      N T D                       (uint8, every presentation of one traversal at once)
    spike lists       4 min(N, c) T D min(1, r)    (int32 per active input, one chunk of c presentations;
                                                    r = encoder.rate_scale bounds the firing probability)
    weights           4 D K x copies              (float32; K = all neurons of the ensemble)
    counts, S^R       8 N K + 8 K P               (int64 counts and the calibration matrix, P places)
    scores            8 R P x 4                   (float64 score matrices of the readout, R of its rows at once:
                                                    a block: the largest of
                                                    :data:`~vprsnn_export.runtime.evaluation.READOUT_BLOCKS` that
                                                    fits, or all N; none in calibration, which reads nothing out)
    raster            N T K                       (bool, per recorded run; state isolation off records one)
    STDP scratch      8 D n x threads              (float32 P^T and D of one module per thread)
    decoded image     4 W H                        (an image of W x H pixels read from its header before
                                                    decoding: up to 4 channels of uint8 while it becomes grey)

The limit (:func:`memory_limit`): ``--memory-limit`` on the command line or :func:`set_memory_limit`,
else the environment variable ``VPRSNN_MEMORY_LIMIT``, else 90 % of the memory the machine has
available now (``MemAvailable`` in /proc/meminfo, else ``os.sysconf``); none when neither can be read.
Sizes are written as a whole number of bytes or with a binary unit: ``512M``, ``8G``, ``1.5T``.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

from .errors import InvalidValueError

ENV_LIMIT = "VPRSNN_MEMORY_LIMIT"
OPTION = "--memory-limit"
AVAILABLE_SHARE = 0.9  # of the available memory: the default limit leaves room for the interpreter and libraries
UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40, "P": 1 << 50}
SIZE = re.compile(r"([0-9]{1,15})(\.[0-9]{1,6})?\s?([KMGTP]?)(i?B)?", re.IGNORECASE)

_explicit_limit: int | None = None


def parse_size(text: str, name: str = OPTION) -> int:
    """Bytes of ``text``: ASCII digits with an optional fraction and binary unit (``8G`` = 8 x 2**30)."""
    match = SIZE.fullmatch(text.strip()) if isinstance(text, str) else None
    if match is None:
        raise InvalidValueError(f"{name}: expected a size such as 512M, 8G or 1.5T, got {text!r}")
    number = float(match.group(1) + (match.group(2) or ""))
    size = int(number * UNITS[match.group(3).upper()])
    if size < 1:
        raise InvalidValueError(f"{name}: the size must be at least one byte, got {text!r}")
    return size


def format_size(size: int) -> str:
    """``size`` bytes in the largest binary unit that keeps the number at least 1: '6.3 GiB'."""
    for unit in ("P", "T", "G", "M", "K"):
        if size >= UNITS[unit]:
            return f"{size / UNITS[unit]:.1f} {unit}iB"
    return f"{size} B"


def available_memory(meminfo: str | None = None) -> int | None:
    """Bytes the machine can give now: MemAvailable of /proc/meminfo (or of ``meminfo``), else os.sysconf."""
    if meminfo is None:
        try:
            with open("/proc/meminfo", encoding="ascii", errors="replace") as handle:
                meminfo = handle.read()
        except OSError:
            meminfo = ""
    found = re.search(r"^MemAvailable:\s+([0-9]{1,15}) kB$", meminfo, re.MULTILINE)
    if found:
        return int(found.group(1)) * 1024
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def set_memory_limit(limit: int | str | None) -> int | None:
    """Use ``limit`` bytes (an int, or a size such as '8G'; None: back to the default); returns the limit now in use."""
    global _explicit_limit
    if limit is None or isinstance(limit, str):
        _explicit_limit = None if limit is None else parse_size(limit, OPTION)
    elif isinstance(limit, bool) or not isinstance(limit, int) or limit < 1:
        raise InvalidValueError(f"memory limit must be a positive number of bytes or a size such as 8G, got {limit!r}")
    else:
        _explicit_limit = limit
    return memory_limit()


def memory_limit() -> int | None:
    """The limit in bytes: :func:`set_memory_limit`'s, else $VPRSNN_MEMORY_LIMIT, else 90 % of the available memory."""
    return _limit_and_source()[0]


def _limit_and_source() -> tuple[int | None, str]:
    """:func:`memory_limit` and, for an error, what sets it."""
    if _explicit_limit is not None:
        return _explicit_limit, f"set by {OPTION}"
    text = os.environ.get(ENV_LIMIT, "").strip()
    if text:
        return parse_size(text, ENV_LIMIT), f"set by {ENV_LIMIT}"
    available = available_memory()
    share = f"{AVAILABLE_SHARE:.0%} of the available memory; {OPTION} or {ENV_LIMIT} sets it"
    return None if available is None else int(available * AVAILABLE_SHARE), share


@dataclass(frozen=True)
class MemoryNeed:
    """The big arrays of one step of a run: (name, bytes) terms."""

    terms: tuple[tuple[str, int], ...]

    @property
    def total(self) -> int:
        return sum(size for _, size in self.terms)


def run_need(
    *,
    presentations: int,
    timesteps: int,
    n_inputs: int,
    n_neurons: int,
    places: int,
    chunk: int,
    rate_scale: float = 1.0,
    rasters: int = 0,
    readout_rows: int | None = None,
    readout_arrays: int = 4,
    block: int | None = None,
) -> MemoryNeed:
    """Presenting ``presentations`` spike trains to a network of ``n_neurons`` and reading out ``places`` places.

    ``rasters``: output rasters kept whole (a recorded run; state isolation off records one internally);
    ``readout_rows``: the queries read out at once (None: all; 0: no readout); ``readout_arrays``: the float64
    (rows x places) arrays alive at once (every strategy's scores, the aggregate at every k, two in the making);
    ``block``: a long route encoded and run ``block`` presentations at a time, its counts and S^R kept as CSR
    (int64 + int32 index per entry, at most T entries per presentation and place; None: all at once, dense).
    """
    rows = presentations if readout_rows is None else min(readout_rows, presentations)
    encoded = presentations if block is None else min(block, presentations)
    counts = (
        8 * n_neurons * (presentations + places)
        if block is None
        else 12 * min(timesteps, n_neurons) * (2 * presentations + places)
    )
    terms = [
        (f"input spikes {encoded} x {timesteps} x {n_inputs}", encoded * timesteps * n_inputs),
        ("spike lists", int(4 * min(presentations, chunk) * timesteps * n_inputs * min(1.0, rate_scale))),
        (f"weights {n_inputs} x {n_neurons} (2 copies)", 4 * n_inputs * n_neurons * 2),
        (f"counts and S^R ({n_neurons} neurons{'' if block is None else ', sparse'})", counts),
    ]
    if block is not None:
        terms.append((f"counts of a block {encoded} x {n_neurons}", 8 * encoded * n_neurons))
    if rows:
        terms.append((f"scores {readout_arrays} x {rows} x {places}", 8 * rows * places * readout_arrays))
    if rasters:
        terms.append(
            (f"raster {presentations} x {timesteps} x {n_neurons}", rasters * presentations * timesteps * n_neurons)
        )
    return MemoryNeed(tuple(terms))


def training_need(
    *, n_modules: int, n_inputs: int, n_neurons: int, timesteps: int, batch: int, threads: int
) -> MemoryNeed:
    """Training ``n_modules`` modules of ``n_neurons`` side by side on batches of ``batch`` presentations."""
    return MemoryNeed(
        (
            (f"weights {n_modules} x {n_inputs} x {n_neurons} (3 copies)", 4 * n_modules * n_inputs * n_neurons * 3),
            (f"STDP scratch {n_inputs} x {n_neurons} x {threads} thread(s)", 8 * n_inputs * n_neurons * threads),
            (f"batch spikes {batch} x {timesteps} x {n_inputs}", batch * timesteps * n_inputs * threads),
            ("batch limits", 4 * n_modules * batch * n_inputs),
        )
    )


def single_need(name: str, size: int) -> MemoryNeed:
    return MemoryNeed(((name, size),))


LOWER_RUN = "fewer places (--places) or timesteps (--timesteps, encoder.timesteps)"
LOWER_TRAINING = (
    "fewer neurons (--neurons), fewer modules (--module-size), fewer --threads or a smaller train.batch_size"
)


def check_memory(need: MemoryNeed, what: str, lower: str, limit: int | None = None) -> None:
    """InvalidValueError (one line) when ``need`` exceeds ``limit`` (default :func:`memory_limit`).

    ``what``: the step (``train``, ``calibration``); ``lower``: the settings that make the need smaller.
    """
    limit, source = _limit_and_source() if limit is None else (limit, "given")
    if limit is None or need.total <= limit:
        return
    name, size = max(need.terms, key=lambda term: term[1])
    raise InvalidValueError(
        f"{what} needs about {format_size(need.total)} of memory (largest: {name}, {format_size(size)}), "
        f"over the limit of {format_size(limit)} ({source}); {lower} lower the need"
    )
