"""Checks of the arrays a compiled kernel indexes: numba does no bounds checking, so every
array a kernel reads or writes is checked before the call (shape, dtype, C-contiguity,
writability) and a bad one is refused with :class:`~vprsnn_export.errors.InvalidValueError`
naming the kernel and the argument. A kernel given arrays that pass these checks stays in bounds.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from ..errors import InvalidValueError

Shape = Sequence[int | None]  # None: any length along that axis


def require_array(
    kernel: str, name: str, array: object, dtypes: Sequence[npt.DTypeLike], shape: Shape, *, writable: bool = False
) -> np.ndarray:
    """``array`` itself if it is a C-contiguous numpy array of one of ``dtypes`` with ``shape``; else refuse it (the
    message is built only then: the checks run before every kernel call, a localiser's frame makes seven)."""

    def refused(got: str) -> InvalidValueError:
        axes = ", ".join("*" if length is None else str(length) for length in shape)
        kinds = "/".join(str(np.dtype(d)) for d in dtypes)
        return InvalidValueError(f"{kernel}: {name} must be a C-contiguous {kinds} array of shape ({axes}), got {got}")

    if not isinstance(array, np.ndarray):
        raise refused(type(array).__name__)
    if not any(array.dtype == d for d in dtypes):
        raise refused(f"dtype {array.dtype}")
    if array.ndim != len(shape) or any(want not in (None, have) for have, want in zip(array.shape, shape, strict=True)):
        raise refused(f"shape {array.shape}")
    if not array.flags.c_contiguous:
        raise refused("a non-contiguous array")
    if writable and not array.flags.writeable:
        raise InvalidValueError(f"{kernel}: {name} is written by the kernel but is read-only")
    return array


def require_int(kernel: str, name: str, value: object, low: int, high: int | None = None) -> int:
    """``value`` as an int in [low, high] (``high`` None: no upper bound); else refuse it."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise InvalidValueError(f"{kernel}: {name} must be an integer, got {type(value).__name__}")
    number = int(value)
    if number < low or (high is not None and number > high):
        bound = f"[{low}, {high}]" if high is not None else f">= {low}"
        raise InvalidValueError(f"{kernel}: {name} must be {bound}, got {number}")
    return number


def require_groups(kernel: str, n_neurons: int, group: object, start: object, stop: object, tile: object) -> None:
    """The neurons [start, stop) in tiles of ``tile``, both whole WTA groups of ``group`` neurons of ``n_neurons``."""
    size = require_int(kernel, "group", group, 1)
    if n_neurons % size:
        raise InvalidValueError(f"{kernel}: group: WTA groups of {size} neurons do not divide {n_neurons} neurons")
    first = require_int(kernel, "start", start, 0, n_neurons)
    last = require_int(kernel, "stop", stop, first, n_neurons)
    width = require_int(kernel, "tile", tile, size)
    for name, value in (("start", first), ("stop", last), ("tile", width)):
        if value % size:
            raise InvalidValueError(f"{kernel}: {name} must be a multiple of the WTA group ({size}), got {value}")
