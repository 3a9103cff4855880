"""Reading a ``.npy`` file that no byte of can run code, crash the process or allocate without bound.

``np.load(path, allow_pickle=True)`` executes whatever the pickle inside an object array says.
VPR-Bench ships its ground truth (``ground_truth_new.npy``) as exactly such an object array, so it
is read here by a restricted unpickler that never hands the pickle to numpy's own rebuilding code:

* the only globals it resolves are numpy's array, dtype and scalar reconstruction names, and each
  resolves to a stand-in of this module (:class:`_ArrayRecipe`, :class:`_DtypeRecipe`,
  :func:`_scalar`) that only records its arguments; any other global (``os.system``,
  ``builtins.exec``, ...) is refused before anything is called;
* a dtype is rebuilt from its type code alone (``i8``, ``f4``, ``O8``, ...), and its pickled state must
  be exactly the state numpy writes for that code (a forged state, flags that make raw bytes object
  pointers, fields or subarrays is refused);
* an object array is rebuilt from its list form only (one Python object per element); a numeric
  array from a bytes buffer whose length is exactly ``prod(shape) * itemsize``;
* the object graph is walked once, iteratively, at most :data:`MAX_DEPTH` levels deep, so no deep
  nesting reaches Python's recursion limit.

The objects it can build are therefore numbers, strings, lists, tuples, dicts and numpy arrays of
plain dtypes. A non-object array is read by ``np.load`` without pickle, after its header's shape and
dtype are checked against the file's length, so nothing is allocated beyond what the file holds.
"""

from __future__ import annotations

import io
import math
import pickle
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataError, brief

MAX_NPY_BYTES = 1 << 30  # a ground-truth file larger than this is not one
MAX_DEPTH = 8  # array -> row -> list -> index is 4; anything deeper is not a ground truth
#: Type codes a pickled dtype may name: booleans, integers, floats and Python objects.
PLAIN_CODES = frozenset(("b1", "i1", "i2", "i4", "i8", "u1", "u2", "u4", "u8", "f2", "f4", "f8", "O8", "O4"))
_MULTIARRAY = ("numpy.core.multiarray", "numpy._core.multiarray")


class _Recipe:
    """A stand-in of a numpy global while unpickling: it records the state the pickle sets, never applies it."""

    state: object = None

    def __setstate__(self, state: object) -> None:
        self.state = state


class _DtypeRecipe(_Recipe):
    """Stand-in for ``numpy.dtype(code, align, copy)``; its state is checked, never applied."""

    def __init__(self, code: object, align: object = False, copy: object = True) -> None:
        self.code: object = code

    def dtype(self) -> np.dtype:
        """The plain dtype named by the code, if the pickled state is exactly the one numpy writes for it."""
        if not isinstance(self.code, str) or self.code not in PLAIN_CODES:
            raise ValueError(f"dtype code {brief(self.code)} is not a plain number or object type")
        base = np.dtype(self.code)
        order = self.state[1] if isinstance(self.state, tuple) and len(self.state) == 8 else None
        if order not in ("<", ">", "|", "="):
            raise ValueError("a dtype state that numpy does not write")
        dtype = base if order in ("|", "=") or base.kind == "O" else base.newbyteorder("<" if order == "<" else ">")
        if self.state != dtype.__reduce__()[2]:
            raise ValueError(f"a forged state for dtype {self.code}")
        return dtype


class _ArrayRecipe(_Recipe):
    """Stand-in for ``numpy.core.multiarray._reconstruct(ndarray, shape, typecode)`` while unpickling."""

    def __init__(self, cls: object, shape: object, typecode: object) -> None:
        if cls is not _NDARRAY:
            raise ValueError("an array of a class other than numpy.ndarray")

    def parts(self) -> tuple[tuple[int, ...], np.dtype, bool, object]:
        """(shape, dtype, Fortran order, data) of the pickled state ``(version, shape, dtype, fortran, data)``."""
        state = self.state
        if not isinstance(state, tuple) or len(state) != 5:
            raise ValueError("an array without its state")
        _, shape, recipe, fortran, data = state
        if not isinstance(shape, tuple) or not all(type(n) is int and n >= 0 for n in shape) or len(shape) > 32:
            raise ValueError(f"an array shape {brief(shape)} that is not a tuple of sizes")
        if not isinstance(recipe, _DtypeRecipe) or type(fortran) is not bool:
            raise ValueError("an array state that numpy does not write")
        return shape, recipe.dtype(), fortran, data


_NDARRAY = object()  # what ``numpy.ndarray`` resolves to: a marker, never called


def _scalar(recipe: object, data: object) -> object:
    """Stand-in for ``numpy.core.multiarray.scalar(dtype, data)``: one number from exactly itemsize bytes."""
    if not isinstance(recipe, _DtypeRecipe):
        raise ValueError("a scalar without a dtype")
    dtype = recipe.dtype()
    if dtype.kind == "O":
        return data
    if not isinstance(data, bytes) or len(data) != dtype.itemsize:
        raise ValueError(f"a {dtype} scalar over a buffer that is not {dtype.itemsize} bytes")
    return np.frombuffer(data, dtype=dtype)[0]


#: (module, name) of the only globals a pickled array may name (numpy 1.x and 2.x spellings) -> its stand-in.
_GLOBALS: dict[tuple[str, str], object] = {
    **{(module, "_reconstruct"): _ArrayRecipe for module in _MULTIARRAY},
    **{(module, "scalar"): _scalar for module in _MULTIARRAY},
    ("numpy", "ndarray"): _NDARRAY,
    ("numpy", "dtype"): _DtypeRecipe,
}


class _ArrayUnpickler(pickle.Unpickler):
    """An unpickler that resolves only :data:`_GLOBALS`, to recording stand-ins, and refuses persistent ids."""

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) not in _GLOBALS:
            raise pickle.UnpicklingError(f"refused global {module[:60]}.{name[:60]}")
        return _GLOBALS[(module, name)]

    def persistent_load(self, pid: Any) -> Any:
        raise pickle.UnpicklingError("refused persistent id")


def _rebuild(root: object) -> object:
    """``root`` with every :class:`_ArrayRecipe` replaced by its array (an object array's elements: its list form)
    and containers rebuilt with their elements replaced, walked iteratively (each object once; the root keeps
    every node alive, so no ``id`` is reused during the walk)."""
    done: dict[int, object] = {}
    stack: list[tuple[object, int, bool]] = [(root, 0, False)]
    while stack:
        node, depth, children_done = stack.pop()
        if id(node) in done:
            continue
        if depth > MAX_DEPTH:
            raise ValueError(f"objects nested more than {MAX_DEPTH} levels deep")
        if isinstance(node, _ArrayRecipe):
            shape, dtype, fortran, data = node.parts()
            if dtype.kind != "O":  # over a buffer of exactly prod(shape) * itemsize bytes
                if not isinstance(data, bytes) or len(data) != math.prod(shape) * dtype.itemsize:
                    raise ValueError(f"a {dtype} array of shape {shape} over a buffer of another length")
                done[id(node)] = np.frombuffer(data, dtype=dtype).reshape(shape, order="F" if fortran else "C").copy()
                continue
            if not isinstance(data, list) or len(data) != math.prod(shape):
                raise ValueError(f"an object array of shape {shape} that is not its list of elements")
            children: list[object] = data
        elif isinstance(node, list | tuple):
            children = list(node)
        elif isinstance(node, dict | set | frozenset | bytearray | _DtypeRecipe):
            raise ValueError(f"a {type(node).__name__} where an array element was expected")
        else:
            done[id(node)] = node
            continue
        if not children_done:
            stack.append((node, depth, True))
            stack.extend((child, depth + 1, False) for child in children if id(child) not in done)
            continue
        items = [done[id(child)] for child in children]
        if isinstance(node, _ArrayRecipe):
            array = np.fromiter(items, dtype=object, count=len(items))  # elements as they are (lists stay lists)
            done[id(node)] = array.reshape(shape, order="F" if fortran else "C")
        else:
            done[id(node)] = items if isinstance(node, list) else tuple(items)
    return done[id(root)]


def load_npy(path: str | Path, what: str = "array") -> np.ndarray:
    """The array stored in the ``.npy`` file ``path``; an object array through the restricted unpickler.

    DataError naming the file for anything that is not one readable ``.npy`` array (an ``.npz`` archive, a
    truncated file, a header whose shape the file cannot hold, a pickle naming any global outside :data:`_GLOBALS`,
    a forged dtype state, an object array given as raw bytes, nesting deeper than :data:`MAX_DEPTH`).
    """
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > MAX_NPY_BYTES:
            raise DataError(f"the {what} file is {size} bytes, more than {MAX_NPY_BYTES}", path)
        raw = path.read_bytes()
    except OSError as exc:
        raise DataError(f"cannot read this {what} ({exc.strerror or exc})", path) from None
    return parse_npy(raw, path, what)


def parse_npy(raw: bytes, path: Path, what: str = "array") -> np.ndarray:
    """:func:`load_npy` of a file's bytes already read (``path`` names it in errors)."""
    stream = io.BytesIO(raw)
    try:
        version = np.lib.format.read_magic(stream)
        if version not in ((1, 0), (2, 0)):
            raise ValueError(f"format version {version[0]}.{version[1]} is not supported")
        read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, fortran, dtype = read_header(stream)
    except (ValueError, SyntaxError, TypeError, EOFError, OverflowError, MemoryError, RecursionError) as exc:
        raise DataError(f"the {what} is not a .npy array file ({str(exc)[:120]})", path) from None
    if dtype.fields is not None or dtype.subdtype is not None:
        raise DataError(f"the {what} has a structured dtype ({str(dtype)[:80]}), expected a plain array", path)
    if not dtype.hasobject:
        body = len(raw) - stream.tell()
        if math.prod(shape) * dtype.itemsize != body:
            raise DataError(
                f"the {what}'s header declares shape {brief(shape, 60)} of {dtype} "
                f"({math.prod(shape) * dtype.itemsize} bytes), the file holds {body}: truncated or corrupt",
                path,
            )
        try:
            return np.load(io.BytesIO(raw), allow_pickle=False)
        except (ValueError, EOFError, OSError) as exc:
            raise DataError(f"the {what} is not a readable .npy array (truncated or corrupt: {exc})", path) from None
    if dtype != np.dtype(object):
        raise DataError(f"the {what} has dtype {dtype}, expected numbers or plain Python objects", path)
    try:
        value = _rebuild(_ArrayUnpickler(stream).load())
    except Exception as exc:  # noqa: BLE001  any failure of a hostile stream is a refusal, never a traceback
        raise DataError(
            f"the {what} holds a pickle that is not a plain array of numbers and lists "
            f"({(str(exc) or type(exc).__name__)[:120]}); refused unread",
            path,
        ) from None
    if not isinstance(value, np.ndarray) or value.shape != shape:
        raise DataError(f"the {what}'s pickle is not the array its header declares (shape {shape})", path)
    return np.asfortranarray(value) if fortran else value
