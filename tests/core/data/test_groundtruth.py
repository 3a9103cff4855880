"""Ground-truth files read strictly (issue 31): no file runs code, no malformed value counts as a match."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest

from vprsnn_export.data.groundtruth import pair_ground_truth, read_ground_truth
from vprsnn_export.errors import DataError
from vprsnn_export.io.npyload import load_npy


class RunsCode:
    """Pickles as a call of ``exec``: the payload of a hostile object array."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (exec, (f"open({str(self.marker)!r}, 'w').write('ran')",))


def object_array(items: list) -> np.ndarray:
    array = np.empty(len(items), dtype=object)
    array[:] = items
    return array


def test_a_pickle_that_would_run_code_is_refused_and_does_not_run(tmp_path):
    marker = tmp_path / "ran.txt"
    path = tmp_path / "summer_winter_GT.npy"
    np.save(path, object_array([RunsCode(marker), [1]]), allow_pickle=True)
    assert b"exec" in path.read_bytes()
    with pytest.raises(DataError, match="refused global builtins.exec"):
        load_npy(path, "ground truth")
    with pytest.raises(DataError, match=str(path)):
        read_ground_truth(path, 2, 2)
    assert not marker.exists()
    # the same pickle through numpy's trusting loader would run: the test's payload is live
    np.load(path, allow_pickle=True)
    assert marker.read_text() == "ran"


def test_an_npz_and_a_truncated_file_are_one_error(tmp_path):
    with open(tmp_path / "a.npy", "wb") as handle:
        np.savez(handle, x=np.eye(2))
    (tmp_path / "b.npy").write_bytes(pickle.dumps([1, 2]))
    np.save(tmp_path / "c.npy", np.eye(40))
    (tmp_path / "c.npy").write_bytes((tmp_path / "c.npy").read_bytes()[:300])
    np.save(tmp_path / "d.npy", object_array([[0], [1]]), allow_pickle=True)
    (tmp_path / "d.npy").write_bytes((tmp_path / "d.npy").read_bytes()[:-5])
    for name in ("a.npy", "b.npy", "c.npy", "d.npy"):
        with pytest.raises(DataError, match="not a .npy array|truncated|pickle"):
            load_npy(tmp_path / name)


def test_vpr_bench_rows_and_per_query_lists_read_as_shipped(tmp_path):
    rows = np.empty((3, 2), dtype=object)
    rows[:, 0] = [2, 0, 1]
    rows[:, 1] = [[4, 5], np.array([0]), (1, np.int64(2))]
    np.save(tmp_path / "rows.npy", rows, allow_pickle=True)
    truth = read_ground_truth(tmp_path / "rows.npy", 6, 3)
    assert truth.shape == (6, 3)
    assert [np.flatnonzero(truth[:, q]).tolist() for q in range(3)] == [[0], [1, 2], [4, 5]]
    np.save(tmp_path / "lists.npy", object_array([[0], [1, 2], [4, 5]]), allow_pickle=True)
    np.testing.assert_array_equal(read_ground_truth(tmp_path / "lists.npy", 6, 3), truth)


BAD_MATRICES = {
    "nan": np.where(np.eye(3) > 0, 1.0, np.nan),
    "minus-one": np.eye(3, dtype=np.int64) - 2 * (1 - np.eye(3, dtype=np.int64)),
    "soft": np.eye(3) * 0.9 + 0.1,
    "strings": np.eye(3).astype(int).astype(str),
    "complex": np.eye(3, dtype=complex),
    "datetime": np.zeros((3, 3), dtype="datetime64[s]"),
    "one-d": np.ones(3),
    "wrong-shape": np.eye(4),
}


@pytest.mark.parametrize("name", sorted(BAD_MATRICES))
def test_a_malformed_matrix_is_one_error_naming_the_file(tmp_path, name):
    path = tmp_path / "summer_winter_GT.npy"
    np.save(path, BAD_MATRICES[name])
    with pytest.raises(DataError, match=str(path)):
        read_ground_truth(path, 3, 3)


BAD_LISTS = {
    "float": [[0.9], [1], [2]],
    "bool": [[True], [1], [2]],
    "negative": [[-1], [1], [2]],
    "outside": [[3], [1], [2]],
    "string": [["0"], [1], [2]],
    "float-array": [np.array([0.0]), [1], [2]],
    "huge": [[2**70], [1], [2]],
    "nested-dict": [{0: 1}, [1], [2]],
}


@pytest.mark.parametrize("name", sorted(BAD_LISTS))
def test_a_malformed_list_is_one_error(tmp_path, name):
    path = tmp_path / "gt.npy"
    np.save(path, object_array(BAD_LISTS[name]), allow_pickle=True)
    with pytest.raises(DataError, match=str(path)):
        read_ground_truth(path, 3, 3)


@pytest.mark.parametrize("cell", ["1_0", "١", "0.5", "-1", "", "x", " 1e0"])
def test_a_csv_cell_that_is_not_an_ascii_integer_is_refused(tmp_path, cell):
    path = tmp_path / "summer_winter_GT.csv"
    path.write_text(f"query,reference\n0,0\n1,{cell}\n", encoding="utf-8")
    with pytest.raises(DataError, match="line 3"):
        read_ground_truth(path, 12, 12)


def test_orientation_is_told_by_the_sizes_and_a_square_asymmetric_matrix_is_refused(tmp_path):
    truth = np.zeros((5, 3), dtype=np.int64)  # GT[reference, query], 5 references, 3 queries
    truth[[0, 2, 4], [0, 1, 2]] = 1
    np.save(tmp_path / "forward.npy", truth)
    np.save(tmp_path / "backward.npy", truth.T)
    np.testing.assert_array_equal(read_ground_truth(tmp_path / "forward.npy", 5, 3), truth > 0)
    np.testing.assert_array_equal(read_ground_truth(tmp_path / "backward.npy", 5, 3), truth > 0)
    np.save(tmp_path / "identity.npy", np.eye(3, dtype=bool))
    assert read_ground_truth(tmp_path / "identity.npy", 3, 3).sum() == 3
    np.save(tmp_path / "shifted.npy", np.eye(3, k=1))
    with pytest.raises(DataError, match="cannot be told from the traversal sizes"):
        read_ground_truth(tmp_path / "shifted.npy", 3, 3)


def test_a_csv_named_query_first_is_swapped_and_files_that_disagree_are_refused(tmp_path):
    (tmp_path / "winter_summer_GT.csv").write_text("query,reference\n0,1\n1,0\n2,2\n", encoding="utf-8")
    truth, path = pair_ground_truth(tmp_path, "summer", "winter", 3, 3)
    assert path.name == "winter_summer_GT.csv" and truth[1, 0] and truth[0, 1]
    (tmp_path / "summer_winter_GT.csv").write_text("query,reference\n0,0\n1,1\n2,2\n", encoding="utf-8")
    with pytest.raises(DataError, match="disagrees with .*winter_summer_GT.csv"):
        pair_ground_truth(tmp_path, "summer", "winter", 3, 3)
    np.save(tmp_path / "summer_winter_GT.npy", np.eye(3))
    (tmp_path / "winter_summer_GT.csv").unlink()
    assert pair_ground_truth(tmp_path, "summer", "winter", 3, 3)[0].sum() == 3


# Crafted pickles built only from numpy's own array-rebuilding globals (issue 45): through numpy's trusting
# loader they read raw bytes as object pointers (SIGSEGV), loop without bound or nest past the recursion limit.
RECONSTRUCT = np._core.multiarray._reconstruct


class Pickled:
    """An object whose pickle is exactly ``(callable, args, state)``."""

    def __init__(self, call, args, state=None) -> None:
        self.reduced = (call, args) if state is None else (call, args, state)

    def __reduce__(self):
        return self.reduced


def forged_array(shape, dtype, data, fortran=False) -> Pickled:
    return Pickled(RECONSTRUCT, (np.ndarray, (0,), b"b"), (1, shape, dtype, fortran, data))


def forged_dtype(code: str, state: tuple) -> Pickled:
    return Pickled(np.dtype, (code, False, True), state)


def write_npy(path: Path, value: object, shape: tuple = (2,)) -> Path:
    """A .npy file with an object header and ``value``'s pickle as its body."""
    with open(path, "wb") as handle:
        np.lib.format.write_array_header_1_0(handle, {"descr": "|O", "fortran_order": False, "shape": shape})
        pickle.dump(value, handle, protocol=3)
    return path


CRAFTED = {
    # raw bytes where an object array's elements belong: numpy reads them as pointers
    "object-over-bytes": (forged_array((2,), np.dtype(object), b"\x41" * 16), "not its list of elements"),
    # an int64 dtype whose state sets the refcount flag: its bytes are decref'd as objects
    "forged-dtype-flags": (
        forged_array((2,), forged_dtype("i8", (3, "<", None, None, None, -1, -1, 1)), b"\x41" * 16),
        "forged state",
    ),
    "forged-dtype-fields": (
        forged_array((2,), forged_dtype("V8", (3, "|", None, ("a",), {"a": (np.dtype(object), 0)}, 8, 1, 63)), b""),
        "not a plain number",
    ),
    # a billion-element reference list over an 8-byte buffer
    "huge-over-small-buffer": (
        [forged_array((10**9,), np.dtype("i8"), b"\x01" * 8), [0]],
        "buffer of another length",
    ),
    "object-scalar-of-bytes": (forged_array((2,), np.dtype(object), [b"\x41" * 8, [0]]), None),
}


@pytest.mark.parametrize("name", sorted(CRAFTED))
def test_a_pickle_built_from_numpys_own_globals_is_refused_or_read_safely(tmp_path, name):
    crafted, refusal = CRAFTED[name]
    path = write_npy(tmp_path / "ground_truth_new.npy", object_array([crafted, [0]]))
    with pytest.raises(DataError, match=str(path)) as caught:
        read_ground_truth(path, 2, 2)
    if refusal is not None:
        assert refusal in str(caught.value)
    assert len(str(caught.value)) < 400


def test_the_forged_pickles_are_live_through_numpys_own_loader(tmp_path):
    """The refusals above guard a real crash: numpy's loader dies on the first (checked in a child process)."""
    import subprocess
    import sys

    path = write_npy(tmp_path / "gt.npy", CRAFTED["forged-dtype-flags"][0])
    code = f"import numpy as np; a = np.load({str(path)!r}, allow_pickle=True); del a; print('survived')"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert result.returncode != 0 or "survived" not in result.stdout or result.stderr


def test_deep_nesting_long_strings_and_cycles_are_one_short_error(tmp_path):
    cyclic: list = [0]
    cyclic.append(cyclic)
    for name, value in {"string": "x" * 20_000_000, "cyclic": cyclic}.items():
        path = write_npy(tmp_path / f"{name}.npy", object_array([value, [1]]))
        with pytest.raises(DataError, match=str(path)) as caught:
            read_ground_truth(path, 2, 2)
        assert len(str(caught.value)) < 400, name
    depth = 200_000  # lists nested 200,000 deep: pickle cannot write them, so the opcodes are written by hand
    path = tmp_path / "deep.npy"
    with open(path, "wb") as handle:
        np.lib.format.write_array_header_1_0(handle, {"descr": "|O", "fortran_order": False, "shape": (2,)})
        handle.write(b"\x80\x03" + b"]" * depth + b"a" * (depth - 1) + b".")
    with pytest.raises(DataError, match="nested more than"):
        read_ground_truth(path, 2, 2)


def test_a_numeric_header_the_file_cannot_hold_is_refused_before_reading(tmp_path):
    path = tmp_path / "summer_winter_GT.npy"
    with open(path, "wb") as handle:
        np.lib.format.write_array_header_1_0(handle, {"descr": "<i8", "fortran_order": False, "shape": (10**6, 10**6)})
        handle.write(b"\x00" * 8)
    with pytest.raises(DataError, match="declares shape"):
        load_npy(path)


def test_numpy_scalars_and_fortran_arrays_in_a_shipped_file_still_read(tmp_path):
    rows = np.empty((2, 2), dtype=object)
    rows[:, 0] = [np.int64(1), np.int32(0)]
    rows[:, 1] = [np.asfortranarray(np.array([[0], [2]])), np.array([1], dtype=">i4")]
    np.save(tmp_path / "rows.npy", rows, allow_pickle=True)
    truth = read_ground_truth(tmp_path / "rows.npy", 3, 2)
    assert [np.flatnonzero(truth[:, q]).tolist() for q in range(2)] == [[1], [0, 2]]
