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
