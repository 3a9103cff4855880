"""Reading a ``.npy`` file that no byte of can run code.

``np.load(path, allow_pickle=True)`` executes whatever the pickle inside an object array says.
VPR-Bench ships its ground truth (``ground_truth_new.npy``) as exactly such an object array, so it
is read here by a restricted unpickler: the only globals it resolves are numpy's array and scalar
reconstruction functions (``_reconstruct``, ``ndarray``, ``dtype``, ``scalar``); any other global
(``os.system``, ``builtins.exec``, ...) is refused before anything is called. The objects it can
build are therefore numbers, strings, lists, tuples, dicts and numpy arrays; a non-object array is
read by ``np.load`` without pickle.
"""

from __future__ import annotations

import io
import pickle
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataError

MAX_NPY_BYTES = 1 << 30  # a ground-truth file larger than this is not one
#: (module, name) of the only globals a pickled array may name (numpy 1.x and 2.x spellings).
ALLOWED_GLOBALS = frozenset(
    (module, name)
    for module in ("numpy.core.multiarray", "numpy._core.multiarray")
    for name in ("_reconstruct", "scalar")
) | frozenset((("numpy", "ndarray"), ("numpy", "dtype")))


class _ArrayUnpickler(pickle.Unpickler):
    """An unpickler that resolves only :data:`ALLOWED_GLOBALS` and refuses persistent ids."""

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) not in ALLOWED_GLOBALS:
            raise pickle.UnpicklingError(f"refused global {module}.{name}")
        return super().find_class(module, name)

    def persistent_load(self, pid: Any) -> Any:
        raise pickle.UnpicklingError("refused persistent id")


def load_npy(path: str | Path, what: str = "array") -> np.ndarray:
    """The array stored in the ``.npy`` file ``path``; an object array through the restricted unpickler.

    DataError naming the file for anything that is not one readable ``.npy`` array (an ``.npz`` archive,
    a truncated file, a pickle naming any global outside :data:`ALLOWED_GLOBALS`).
    """
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > MAX_NPY_BYTES:
            raise DataError(f"the {what} file is {size} bytes, more than {MAX_NPY_BYTES}", path)
        raw = path.read_bytes()
    except OSError as exc:
        raise DataError(f"cannot read this {what} ({exc.strerror or exc})", path) from None
    stream = io.BytesIO(raw)
    try:
        version = np.lib.format.read_magic(stream)
        if version not in ((1, 0), (2, 0)):
            raise ValueError(f"format version {version[0]}.{version[1]} is not supported")
        read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, fortran, dtype = read_header(stream)
    except (ValueError, SyntaxError, TypeError, EOFError, OverflowError) as exc:
        raise DataError(f"the {what} is not a .npy array file ({exc})", path) from None
    if not dtype.hasobject:
        try:
            return np.load(io.BytesIO(raw), allow_pickle=False)
        except (ValueError, EOFError, OSError) as exc:
            raise DataError(f"the {what} is not a readable .npy array (truncated or corrupt: {exc})", path) from None
    try:
        value = _ArrayUnpickler(stream).load()
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, IndexError, KeyError) as exc:
        raise DataError(
            f"the {what} holds a pickle that is not a plain array of numbers and lists ({exc}); refused unread", path
        ) from None
    except Exception as exc:  # noqa: BLE001  any other failure of a hostile stream is still a refusal
        raise DataError(f"the {what} holds an unreadable pickle ({type(exc).__name__}); refused", path) from None
    if not isinstance(value, np.ndarray) or value.shape != tuple(shape):
        raise DataError(f"the {what}'s pickle is not the array its header declares (shape {tuple(shape)})", path)
    return np.asfortranarray(value) if fortran else value
