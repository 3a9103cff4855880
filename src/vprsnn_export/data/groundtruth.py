"""Ground-truth files of a (reference, query) pair of traversals, read strictly.

Every form becomes one boolean matrix ``GT[reference, query]`` (True: that reference frame is a correct match of
that query frame):

* a 0/1 matrix in a ``.npy`` (bool, integer or float holding only 0 and 1), ``(references, queries)`` or
  ``(queries, references)``, told apart by the traversal sizes. A square matrix (equal sizes) must be symmetric
  (the identity is), else its orientation is ambiguous and it is refused: give a CSV of pairs instead. Soft
  ground truth (values strictly between 0 and 1) is refused;
* VPR-Bench's ``ground_truth_new.npy``: an ``(N, 2)`` object array of ``[query index, list of reference
  indices]``, or a 1-D object array of one list of reference indices per query, read (pickled) by
  :func:`vprsnn_export.io.npyload.load_npy`, which runs no code;
* a CSV with columns ``query,reference`` (ASCII decimal integers), one row per matching pair.

Anything else (NaN, -1, 0.1, strings, complex, datetime, booleans or floats used as indices, ``1_0``, non-ASCII
digits, an index outside the traversal) is a DataError naming the file.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable, Sequence
from numbers import Integral
from pathlib import Path

import numpy as np

from ..arguments import ascii_uint
from ..errors import DataError, brief
from ..io.fileio import sha256_bytes
from ..io.npyload import MAX_NPY_BYTES, parse_npy

GT_SUFFIXES = ("_GT.npy", "_GT.csv")
VPR_BENCH_GT = "ground_truth_new.npy"  # VPR-Bench: <dataset>/ref/, <dataset>/query/, ground_truth_new.npy
VPR_BENCH_PAIR = ("ref", "query")


def ground_truth_files(folder: Path, reference: str, query: str) -> list[tuple[Path, bool]]:
    """The files that hold the ground truth of (reference, query), each with whether its name puts the
    reference first: ``<reference>_<query>_GT.npy|csv``, ``<query>_<reference>_GT.npy|csv`` (LENS names
    either way) and VPR-Bench's ``ground_truth_new.npy`` for the pair (``ref``, ``query``)."""
    found = [
        (folder / f"{first}_{second}{suffix}", first == reference)
        for first, second in ((reference, query), (query, reference))
        for suffix in GT_SUFFIXES
    ]
    if (reference, query) == VPR_BENCH_PAIR:
        found.append((folder / VPR_BENCH_GT, True))
    return [(path, forward) for path, forward in found if path.is_file()]


#: Each ground-truth file read in this process, by (path, size, mtime, inode): its bytes' sha256 and the
#: matrices read from it. A command reads a file once (load, fingerprint and scoring all ask here); a file
#: changed on disk is read again.
_READ: dict[tuple, tuple[str, dict[tuple[int, int, bool], np.ndarray]]] = {}
MAX_REMEMBERED = 8


def opened(path: Path) -> tuple[tuple, bytes | None]:
    """The file's key and, when this process has not read it yet, its bytes (read once, size-checked)."""
    try:
        stat = path.stat()
        key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns, stat.st_ino)
        if key in _READ:
            return key, None
        if stat.st_size > MAX_NPY_BYTES:
            raise DataError(f"the ground truth file is {stat.st_size} bytes, more than {MAX_NPY_BYTES}", path)
        raw = path.read_bytes()
    except OSError as exc:
        raise DataError(f"cannot read this ground truth ({exc.strerror or exc})", path) from None
    if len(_READ) >= MAX_REMEMBERED:
        _READ.pop(next(iter(_READ)))
    _READ[key] = (sha256_bytes(raw), {})
    return key, raw


def ground_truth_digest(path: Path) -> str:
    """sha256 of the file's bytes (read at most once per process and version of the file)."""
    key, _ = opened(path)
    return _READ[key][0]


def read_ground_truth(path: Path, n_reference: int, n_query: int, reference_first: bool = True) -> np.ndarray:
    """The file as a boolean matrix ``GT[reference, query]`` of shape (n_reference, n_query), read-only; DataError
    on any defect. ``reference_first``: a CSV's file name puts the reference traversal first (its columns are
    then query,reference of that naming; otherwise the two are swapped). Read once per process and file version."""
    key, raw = opened(path)
    shape = (n_reference, n_query, reference_first or path.suffix.lower() != ".csv")  # a .npy reads either way
    matrices = _READ[key][1]
    if shape not in matrices:
        if raw is None:
            raw = path.read_bytes()  # the same version, read for another shape (a rare second pairing)
        if path.suffix.lower() == ".csv":
            matrix = _csv_matrix(raw, path, n_reference, n_query, reference_first)
        else:
            array = parse_npy(raw, path, "ground truth")
            matrix = (_object_matrix if array.dtype.hasobject else _numeric_matrix)(array, path, n_reference, n_query)
        matrix.setflags(write=False)
        matrices[shape] = matrix
    return matrices[shape]


def _numeric_matrix(raw: np.ndarray, path: Path, n_reference: int, n_query: int) -> np.ndarray:
    if raw.dtype.kind not in "biuf" or raw.ndim != 2:
        raise DataError(
            f"expected a 2-D 0/1 matrix (bool, integer or float), got shape {raw.shape} dtype {raw.dtype}", path
        )
    values = raw.astype(np.float64) if raw.dtype.kind == "f" else raw
    bad = ~((values == 0) | (values == 1))
    if bad.any():
        where = tuple(int(i) for i in np.argwhere(bad)[0])
        raise DataError(
            f"entries must be 0 or 1 (soft ground truth is not supported): {raw[where].item()!r} at {list(where)}", path
        )
    matrix = values != 0
    forward, backward = raw.shape == (n_reference, n_query), raw.shape == (n_query, n_reference)
    if forward and backward and not np.array_equal(matrix, matrix.T):
        raise DataError(
            f"a square {raw.shape} matrix that is not symmetric: whether it is GT[reference, query] or "
            "GT[query, reference] cannot be told from the traversal sizes; give the pairs as a CSV "
            "(<reference>_<query>_GT.csv with columns query,reference)",
            path,
        )
    if forward or backward:
        return matrix if forward else matrix.T
    raise DataError(
        f"matrix of shape {raw.shape}, expected (references, queries) = {(n_reference, n_query)} "
        f"or (queries, references) = {(n_query, n_reference)}",
        path,
    )


def _index_list(value: object, what: str, path: Path, high: int) -> np.ndarray:
    """Indices ``0..high-1`` from an int, a list/tuple of ints or an integer array (never bool or float)."""
    items: Sequence[object]
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "iu" and not (value.dtype.hasobject or value.size == 0):
            raise DataError(f"{what} is an array of {value.dtype}, expected integer indices", path)
        items = list(value.reshape(-1))
    elif isinstance(value, list | tuple):
        items = value
    else:
        items = [value]
    if len(items) > high:
        raise DataError(f"{what} names {len(items)} references, more than the {high} of the traversal", path)
    for item in items:
        if isinstance(item, bool | np.bool_) or not isinstance(item, Integral):
            raise DataError(f"{what} holds {brief(item)} ({type(item).__name__}), expected integer indices", path)
        if not 0 <= int(item) < high:
            raise DataError(f"{what} names index {int(item)}, outside 0..{high - 1}", path)
    return np.asarray(items, dtype=np.int64)  # every item an integer index, checked above


def _object_matrix(raw: np.ndarray, path: Path, n_reference: int, n_query: int) -> np.ndarray:
    """VPR-Bench's (N, 2) [query, references] rows, or one list of references per query."""
    matrix = np.zeros((n_reference, n_query), dtype=bool)
    if raw.ndim == 2 and raw.shape[1] == 2:
        for row, query in enumerate(raw[:, 0]):
            if isinstance(query, bool | np.bool_) or not isinstance(query, Integral) or not 0 <= int(query) < n_query:
                raise DataError(f"row {row}: query index {brief(query)} is not an integer in 0..{n_query - 1}", path)
        queries = [int(query) for query in raw[:, 0]]
        if len(set(queries)) != len(queries):
            raise DataError("the query column lists a query index twice", path)
        lists = raw[:, 1]
    elif raw.ndim == 1 and len(raw) == n_query:
        queries, lists = list(range(n_query)), raw
    else:
        raise DataError(
            f"expected VPR-Bench's (N, 2) rows of [query index, reference indices] or one list of reference "
            f"indices per query ({n_query}), got an object array of shape {raw.shape}",
            path,
        )
    for query, matches in zip(queries, lists, strict=True):
        matrix[_index_list(matches, f"query {query}'s reference list", path, n_reference), query] = True
    return matrix


def _csv_matrix(raw: bytes, path: Path, n_reference: int, n_query: int, reference_first: bool) -> np.ndarray:
    """Rows ``query,reference`` of ASCII decimal integers; with ``reference_first`` False the names are swapped."""
    rows_of, cols_of = (n_query, n_reference) if reference_first else (n_reference, n_query)
    try:
        reader = csv.DictReader(io.StringIO(raw.decode("utf-8-sig"), newline=""))
        if reader.fieldnames is None or not {"query", "reference"} <= {f.strip() for f in reader.fieldnames}:
            raise DataError(f"expected a CSV with columns query,reference, got {reader.fieldnames}", path)
        pairs = []
        for row in reader:
            cells = {key.strip(): (value or "").strip() for key, value in row.items() if key is not None}
            query, reference = ascii_uint(cells.get("query", "")), ascii_uint(cells.get("reference", ""))
            if query is None or reference is None:
                raise DataError(
                    f"line {reader.line_num}: {cells.get('query')!r},{cells.get('reference')!r} are not "
                    "ASCII decimal integers",
                    path,
                )
            if query >= rows_of or reference >= cols_of:
                raise DataError(
                    f"line {reader.line_num}: query {query} or reference {reference} is outside "
                    f"0..{rows_of - 1} / 0..{cols_of - 1}",
                    path,
                )
            pairs.append((query, reference))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise DataError(f"expected a UTF-8 CSV with integer columns query,reference ({exc})", path) from None
    if not pairs:
        raise DataError("the ground-truth CSV lists no pairs", path)
    index = np.asarray(pairs, dtype=np.int64)
    matrix = np.zeros((cols_of, rows_of), dtype=bool)
    matrix[index[:, 1], index[:, 0]] = True
    return matrix if reference_first else matrix.T


def pair_ground_truth(
    folder: Path, reference: str, query: str, n_reference: int, n_query: int
) -> tuple[np.ndarray, Path] | None:
    """GT[reference, query] from every file of the pair (:func:`ground_truth_files`), which must agree;
    None without one. DataError naming both files when two disagree."""
    found = ground_truth_files(folder, reference, query)
    read = ((read_ground_truth(path, n_reference, n_query, forward), path) for path, forward in found)
    return agreeing(read, ": keep one of the two")


def agreeing(found: Iterable[tuple[np.ndarray, Path]], advice: str) -> tuple[np.ndarray, Path] | None:
    """The first (matrix, file) of ``found`` (None without one), read in turn; DataError naming the first file and
    the first later one whose matrix differs (then ``advice``)."""
    items = iter(found)
    first = next(items, None)
    if first is not None:
        for matrix, path in items:
            if not np.array_equal(matrix, first[0]):
                raise DataError(f"this ground truth disagrees with {path}{advice}", first[1])
    return first
