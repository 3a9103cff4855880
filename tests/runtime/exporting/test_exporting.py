"""A deploy folder is written as a whole: never mixed, never half-replaced, checked on read."""

from __future__ import annotations

import json

import pytest

from vprsnn_export.cli import main
from vprsnn_export.errors import ModelFileError
from vprsnn_export.runtime.exporting import read_export
from vprsnn_export.runtime.exporting.folder import MANIFEST_NAME
from vprsnn_export.targets import onnx_target


@pytest.fixture(scope="module")
def model(quantised_model):
    """The session's 4-bit model file (tests/conftest.py)."""
    return str(quantised_model)


def export(model, out, *extra):
    return main(["export", model, "--to", "nir,loihi,onnx", "--out", str(out), "--quiet", *extra])


def test_reexport_needs_force_and_replaces_the_folder_whole(model, tmp_path, capsys):
    out = tmp_path / "deploy"
    assert export(model, out) == 0
    first = read_export(out)
    assert {t: [f.path.name for f in files] for t, files in first.files.items()}["onnx"] == ["model.onnx"]
    (out / "stray.txt").write_text("from the old folder")
    assert export(model, out) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "earlier export" in err and "--force" in err
    assert export(model, out, "--to", "nir", "--force") == 0
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST_NAME, "model.nir"]  # nothing of the old folder left
    assert [p.name for p in tmp_path.iterdir()] == ["deploy"]  # no staging or lock files left beside it


def test_a_folder_with_other_files_or_a_file_is_refused(model, tmp_path, capsys):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep me")
    assert export(model, tmp_path / "mine", "--force") == 2
    assert "no export.json" in capsys.readouterr().err
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep me"
    (tmp_path / "file").write_text("x")
    assert export(model, tmp_path / "file") == 2
    assert "is not a folder" in capsys.readouterr().err


def test_an_interrupted_export_leaves_the_previous_folder_as_it_was(model, tmp_path, monkeypatch):
    out = tmp_path / "deploy"
    assert export(model, out) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(onnx_target, "write_onnx", interrupted)  # the registry loads it per call
    assert export(model, out, "--force") == 130
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    assert [p.name for p in tmp_path.iterdir()] == ["deploy"]
    read_export(out)


def test_read_export_detects_a_changed_or_missing_file(model, tmp_path):
    out = tmp_path / "deploy"
    assert export(model, out) == 0
    moved = tmp_path / "elsewhere"
    out.rename(moved)
    assert read_export(moved).kind == "fixed-point model"  # a moved folder still reads
    (moved / "model.onnx").write_bytes(b"other")
    with pytest.raises(ModelFileError, match="sha256 mismatch"):
        read_export(moved)
    (moved / "model.onnx").unlink()
    with pytest.raises(ModelFileError, match="missing"):
        read_export(moved)
    (moved / MANIFEST_NAME).write_text(json.dumps({"files": 3}))
    with pytest.raises(ModelFileError, match="corrupt"):
        read_export(moved)


def test_export_json_states_the_cost_per_query(model, tmp_path, capsys):
    out = tmp_path / "deploy"
    assert export(model, out, "--check", "--check-samples", "4") == 0
    assert "Loihi 1 estimate" in capsys.readouterr().out
    cost = json.loads((out / MANIFEST_NAME).read_text())["cost"]
    assert cost["steps"] == 20 and cost["synaptic_events_per_input_spike"] == 16
    per_query = cost["per_query"]
    assert per_query["queries"] == 4 and per_query["synaptic_events"] == pytest.approx(16 * per_query["input_spikes"])
    (estimate,) = cost["estimates"]
    assert estimate["chip"] == "Loihi 1" and estimate["energy_uj"] > 0 and estimate["latency_ms"] > 0
    assert read_export(out).cost == cost
