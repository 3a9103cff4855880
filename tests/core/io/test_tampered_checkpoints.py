"""Tampered checkpoint files: each defect is one ModelFileError naming the file, never a traceback."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest
from scipy import sparse

from vprsnn_export.cli import main
from vprsnn_export.errors import ModelFileError
from vprsnn_export.io.checkpoint import load_checkpoint
from vprsnn_export.io.fileio import META_KEY


@pytest.fixture(scope="module")
def good(tiny_checkpoint):
    """The session's tiny checkpoint (tests/conftest.py) as its header and arrays."""
    with np.load(tiny_checkpoint) as npz:
        arrays = {name: npz[name] for name in npz.files}
    meta = json.loads(arrays.pop(META_KEY).tobytes().decode())
    return meta, arrays


def write(path, meta, arrays):
    header = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    np.savez(path, **{META_KEY: header}, **arrays)
    return path


HEADER_EDITS = {
    "header is a list": lambda m: [m],
    "config is a string": lambda m: {**m, "config": "x"},
    "config is a list": lambda m: {**m, "config": [1]},
    "seed is a string": lambda m: {**m, "config": {**m["config"], "seed": "one"}},
    "timesteps is null": lambda m: {**m, "config": {**m["config"], "encoder": {"timesteps": None}}},
    "traversals is a string": lambda m: {**m, "reference_traversals": "summer"},
    "data is a list": lambda m: {**m, "data": ["x"]},
    "history is a mapping": lambda m: {**m, "history": {"a": 1}},
    "format is another": lambda m: {**m, "format": "other"},
    "package_version is a list": lambda m: {**m, "package_version": [1]},
    "data places is text": lambda m: {**m, "data": {**m["data"], "places": "abc"}},
    "data source is a huge synthetic route": lambda m: {**m, "data": {"source": "synthetic:100000000000"}},
    "no reference traversal": lambda m: {**m, "reference_traversals": []},
}


def as_sparse(arrays, data=None, indices=None, indptr=None):
    """``arrays`` with its calibration written as a long route's CSR arrays, any of them replaced."""
    csr = sparse.csr_array(arrays["calibration"])
    parts = {"data": csr.data, "indices": csr.indices, "indptr": csr.indptr}
    given = {"data": data, "indices": indices, "indptr": indptr}
    out = {k: v for k, v in arrays.items() if k != "calibration"}
    return out | {f"calibration_{k}": parts[k] if given[k] is None else given[k](parts[k]) for k in parts}


ARRAY_EDITS = {
    "sparse calibration, an index past the places": lambda a: as_sparse(a, indices=lambda i: i + 1000),
    "sparse calibration, indptr too short": lambda a: as_sparse(a, indptr=lambda p: p[:-1]),
    "sparse calibration, indptr falling": lambda a: as_sparse(a, indptr=lambda p: p[::-1].copy()),
    "sparse calibration, negative counts": lambda a: as_sparse(a, data=lambda d: -d),
    "sparse calibration, float counts": lambda a: as_sparse(a, data=lambda d: d + 0.5),
    "sparse calibration, 2-D data": lambda a: as_sparse(a, data=lambda d: d[:, None]),
    "sparse calibration, no indptr": lambda a: {k: v for k, v in as_sparse(a).items() if k != "calibration_indptr"},
    "0-d reference ids": lambda a: {**a, "reference_place_ids": np.array(3)},
    "duplicate reference ids": lambda a: {**a, "reference_place_ids": np.zeros_like(a["reference_place_ids"])},
    "float reference ids": lambda a: {**a, "reference_place_ids": a["reference_place_ids"].astype(float)},
    "zero thresholds": lambda a: {**a, "thresholds": np.zeros_like(a["thresholds"])},
    "negative thresholds": lambda a: {**a, "thresholds": -a["thresholds"]},
    "huge weights": lambda a: {**a, "weights": np.full_like(a["weights"], 1e30)},
    "NaN weights": lambda a: {**a, "weights": np.full_like(a["weights"], np.nan)},
    "missing calibration": lambda a: {k: v for k, v in a.items() if k != "calibration"},
    "wrong weight shape": lambda a: {**a, "weights": a["weights"][:10]},
    "thresholds of 1e30": lambda a: {**a, "thresholds": np.full_like(a["thresholds"], 1e30)},
    "reference ids beyond 2**53": lambda a: {**a, "reference_place_ids": a["reference_place_ids"] + 10**18},
    "an object array (pickled)": lambda a: {**a, "weights": np.array(["garbage"], dtype=object)},
}


@pytest.mark.parametrize("edit", sorted(HEADER_EDITS))
def test_tampered_headers_are_one_clear_error(good, tmp_path, edit):
    meta, arrays = good
    path = write(tmp_path / "bad.npz", HEADER_EDITS[edit](json.loads(json.dumps(meta))), arrays)
    with pytest.raises(ModelFileError) as caught:
        load_checkpoint(path)
    assert str(path) in str(caught.value)


@pytest.mark.parametrize("edit", sorted(ARRAY_EDITS))
def test_tampered_arrays_are_one_clear_error(good, tmp_path, edit):
    meta, arrays = good
    path = write(tmp_path / "bad.npz", meta, ARRAY_EDITS[edit](dict(arrays)))
    with pytest.raises(ModelFileError) as caught:
        load_checkpoint(path)
    assert str(path) in str(caught.value)


def test_truncated_file_through_the_cli(good, tmp_path, capsys):
    meta, arrays = good
    path = write(tmp_path / "net.npz", meta, arrays)
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    assert main(["evaluate", str(path), "--query", "winter"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"error: {path}")


def test_foreign_members_and_plain_npy_files(good, tmp_path):
    meta, arrays = good
    path = write(tmp_path / "member.npz", meta, arrays)
    with zipfile.ZipFile(path, "a") as archive:
        archive.writestr("calibration_extra.npy", b"garbage")
    with pytest.raises(ModelFileError, match="not .npy arrays"):
        load_checkpoint(path)
    np.save(tmp_path / "plain.npy", arrays["weights"])
    (tmp_path / "plain.npy").rename(tmp_path / "plain.npz")
    with pytest.raises(ModelFileError, match="single .npy array"):
        load_checkpoint(tmp_path / "plain.npz")
    with pytest.raises(ModelFileError, match="empty checkpoint path"):
        load_checkpoint("")
