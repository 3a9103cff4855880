"""A deploy folder is written as a whole: never mixed, never half-replaced, checked on read."""

from __future__ import annotations

import json

import cv2
import pytest

from vprsnn_export.cli import main
from vprsnn_export.data.synthetic import synthetic_route
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


# ------------------------------------------------------------------ files stay in their folder (issue 31)


def edit_manifest(folder, change):
    data = json.loads((folder / MANIFEST_NAME).read_text())
    change(data)
    (folder / MANIFEST_NAME).write_text(json.dumps(data))


def test_export_json_records_paths_relative_to_its_folder_and_reads_from_anywhere(model, tmp_path, monkeypatch, capsys):
    out = tmp_path / "deploy"
    assert export(model, out) == 0
    listed = json.loads((out / MANIFEST_NAME).read_text())["files"]
    assert listed["onnx"][0]["path"] == "model.onnx" and listed["loihi"][0]["path"].startswith("loihi/")
    moved = tmp_path / "renamed"
    out.rename(moved)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    result = read_export(moved)
    assert result.written("onnx") == moved / "model.onnx" and result.folder == moved
    frames = synthetic_route(3, ("winter",))["winter"]
    for index, frame in enumerate(frames):
        cv2.imwrite(str(elsewhere / f"f{index}.png"), frame)
    capsys.readouterr()
    assert main(["localize", model, "--onnx", str(moved), "--frames", str(elsewhere), "--quiet"]) == 0
    assert len(capsys.readouterr().out.splitlines()) == 3  # one decision per frame, by the checked graph


@pytest.mark.parametrize(
    "path", ["../evil.onnx", "deploy/../evil.onnx", "sub/../../evil.onnx", "/tmp/evil.onnx", "."], ids=str
)
def test_a_listed_path_that_leaves_the_folder_is_refused(model, tmp_path, path):
    out = tmp_path / "deploy"
    assert export(model, out) == 0
    (tmp_path / "evil.onnx").write_bytes((out / "model.onnx").read_bytes())  # same bytes: the hash would pass
    edit_manifest(out, lambda data: data["files"]["onnx"][0].update(path=path))
    with pytest.raises(ModelFileError, match="leaves its folder|absolute path|outside its folder"):
        read_export(out)


def test_a_symbolic_link_out_of_the_folder_is_refused(model, tmp_path):
    out = tmp_path / "deploy"
    assert export(model, out) == 0
    (tmp_path / "evil.onnx").write_bytes((out / "model.onnx").read_bytes())
    (out / "model.onnx").unlink()
    (out / "model.onnx").symlink_to(tmp_path / "evil.onnx")
    with pytest.raises(ModelFileError, match="resolves outside its folder"):
        read_export(out)


def test_localize_runs_the_graph_it_checked_not_one_of_the_same_name_in_the_working_directory(
    model, tmp_path, monkeypatch
):
    good = tmp_path / "good"
    assert export(model, good) == 0
    work = tmp_path / "work"
    (work / "deploy").mkdir(parents=True)
    (work / "deploy" / "model.onnx").write_bytes(b"not a graph")  # what the recorded cwd path would name
    edit_manifest(good, lambda data: data.update(folder="deploy"))
    edit_manifest(good, lambda data: [e.update(path="deploy/" + e["path"]) for e in data["files"]["onnx"]])
    monkeypatch.chdir(work)
    assert read_export(good).written("onnx") == good / "model.onnx"  # an earlier version's cwd-relative path


@pytest.mark.parametrize("name", ["../network.npz", "/tmp/network.npz", "sub/network.npz", "", 5], ids=str)
def test_a_loihi_header_naming_an_arrays_file_outside_its_folder_is_refused(model, tmp_path, name):
    from vprsnn_export.targets.loihi_target import read_loihi

    out = tmp_path / "deploy"
    assert export(model, out) == 0
    head = out / "loihi" / "network.json"
    (tmp_path / "network.npz").write_bytes((out / "loihi" / "network.npz").read_bytes())
    header = json.loads(head.read_text())
    header["arrays"]["file"] = name
    head.write_text(json.dumps(header))
    with pytest.raises(ModelFileError, match="arrays file"):
        read_loihi(head)


def test_a_file_run_from_a_deploy_folder_is_checked_against_export_json(model, tmp_path, capsys):
    """Issue 45: a bit-flipped ONNX file given by its own path is refused before it runs, like its folder."""
    import cv2
    import numpy as np

    from vprsnn_export.runtime.exporting.source import check_against_manifest

    out = tmp_path / "deploy"
    assert export(model, out) == 0
    assert check_against_manifest(out / "model.onnx") == out / "model.onnx"
    flipped = bytearray((out / "model.onnx").read_bytes())
    flipped[len(flipped) // 2] ^= 0xFF
    (out / "model.onnx").write_bytes(bytes(flipped))
    with pytest.raises(ModelFileError, match="differs from what export wrote"):
        check_against_manifest(out / "model.onnx")
    frames = tmp_path / "frames"
    frames.mkdir()
    cv2.imwrite(str(frames / "0.png"), np.full((32, 64), 128, np.uint8))
    assert main(["localize", str(model), "--frames", str(frames), "--onnx", str(out / "model.onnx")]) == 2
    assert "differs from what export wrote" in capsys.readouterr().err
    loose = tmp_path / "loose.onnx"  # no export.json beside it: nothing to check against
    loose.write_bytes(bytes(flipped))
    assert check_against_manifest(loose) == loose
