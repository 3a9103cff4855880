"""Checks of arguments at the library's boundary (one InvalidValueError naming the argument) and strict parsing
of numbers written as text: ASCII decimal only (``int()`` also accepts '²', Arabic-Indic digits, '_' and spaces).
"""

from __future__ import annotations

import numbers
import os
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .errors import InvalidValueError

ASCII_UINT = re.compile(r"[0-9]{1,19}")  # up to 19 digits: at most about 10**19, beyond any count used here
ASCII_INT = re.compile(r"-?[0-9]{1,19}")


def ascii_uint(text: str) -> int | None:
    """The integer of ``text`` when it is 1-19 ASCII decimal digits (nothing else, not even spaces); else None."""
    return int(text) if isinstance(text, str) and ASCII_UINT.fullmatch(text) else None


def ascii_int(text: str) -> int | None:
    """As :func:`ascii_uint`, with an optional leading '-'."""
    return int(text) if isinstance(text, str) and ASCII_INT.fullmatch(text) else None


def require_type(name: str, value: object, kind: type | tuple[type, ...]) -> None:
    """InvalidValueError naming ``name`` unless ``value`` is an instance of ``kind``."""
    if not isinstance(value, kind):
        kinds = kind if isinstance(kind, tuple) else (kind,)
        wanted = " or ".join(k.__name__ for k in kinds)
        raise InvalidValueError(f"{name} must be a {wanted}, got {type(value).__name__}")


def require_integer(name: str, value: object, low: int, high: int) -> int:
    """``value`` as an int in [low, high] (a Python or numpy integer, not a bool, float or string)."""
    number = None if isinstance(value, bool) or not isinstance(value, numbers.Integral) else int(value)
    if number is None or not low <= number <= high:
        shown = repr(value) if number is None else number
        raise InvalidValueError(f"{name} must be an integer from {low} to {high}, got {shown}")
    return number


MAX_PLACE_ID = 1 << 53  # ids beyond 2**53 are lost in float64


def check_place_ids(place_ids: Sequence[int] | np.ndarray, name: str = "place_ids") -> np.ndarray:
    """Place ids as a 1-D int64 array when each is an integer in [0, 2**53]; InvalidValueError naming ``name``."""
    try:
        values = np.asarray(place_ids)
    except (TypeError, ValueError) as exc:
        raise InvalidValueError(f"{name} must be a 1-D array of integers ({exc})") from None
    if values.ndim != 1 or (values.size and values.dtype.kind not in "iuf"):
        raise InvalidValueError(f"{name} must be a 1-D array of integers, got shape {values.shape} {values.dtype}")
    if values.size and (
        values.dtype.kind == "f"
        and not np.all(np.isfinite(values) & (values == np.round(values)))
        or values.min() < 0
        or values.max() > MAX_PLACE_ID
    ):
        raise InvalidValueError(f"{name} must be whole numbers in [0, 2**53]")
    return values.astype(np.int64)


def require_path(name: str, value: object) -> Path:
    """``value`` (a str or os.PathLike naming a file) as a Path; InvalidValueError naming ``name`` otherwise."""
    if isinstance(value, bool) or not isinstance(value, str | os.PathLike):
        raise InvalidValueError(f"{name} must be a path (str or os.PathLike), got {type(value).__name__}")
    if "\0" in str(value):
        raise InvalidValueError(f"{name} must not contain a NUL character, got {str(value)!r}")
    return Path(value)


def require_choice(name: str, value: object, choices: Sequence[str]) -> str:
    """``value`` when it is one of the strings ``choices``; InvalidValueError naming ``name`` otherwise."""
    if not isinstance(value, str) or value not in choices:
        raise InvalidValueError(f"{name} must be one of {', '.join(choices)}, got {value!r}")
    return value


def require_bool(name: str, value: object) -> bool:
    """``value`` when it is a bool (or numpy bool); InvalidValueError naming ``name`` otherwise."""
    if not isinstance(value, bool | np.bool_):
        raise InvalidValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def require_names(name: str, value: object) -> list[str]:
    """A non-empty list of distinct non-empty names (not a bare string, which is a sequence of letters)."""
    if isinstance(value, str) or not isinstance(value, Sequence) or not value:
        raise InvalidValueError(f"{name} must be a non-empty list of names, got {value!r}")
    if not all(isinstance(v, str) and v for v in value) or len(set(value)) != len(value):
        raise InvalidValueError(f"{name} must hold distinct non-empty names, got {list(value)!r}")
    return list(value)


def real_array(name: str, value: object) -> np.ndarray:
    """``value`` as a float64 array; InvalidValueError naming ``name`` when it holds anything but real numbers."""
    if isinstance(value, str | bytes):
        raise InvalidValueError(f"{name} must be an array of numbers, got {type(value).__name__}")
    try:
        array = np.asarray(value)
        if array.dtype.kind not in "biuf":
            raise TypeError(f"dtype {array.dtype}")
        return array.astype(np.float64, copy=False)
    except (TypeError, ValueError) as exc:
        raise InvalidValueError(f"{name} must be an array of real numbers ({exc})") from None


def real_number(name: str, value: object) -> float:
    """``value`` (an int or float, not a bool or string) as a float; InvalidValueError naming ``name`` otherwise."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InvalidValueError(f"{name} must be a number, got {value!r}")
    return float(value)
