"""`vprsnn-export localize`: folders, a video and stdin; --calibrate and the stored operating point; real frames."""

from __future__ import annotations

import io
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from vprsnn_export.cli import main
from vprsnn_export.config import Config
from vprsnn_export.data.dataset import Dataset, load_dataset, read_manifest
from vprsnn_export.data.synthetic import synthetic_route
from vprsnn_export.export.model import save_fixed_point
from vprsnn_export.io.checkpoint import Checkpoint, checkpoint_sha256, save_checkpoint
from vprsnn_export.runtime.deployment import deploy
from vprsnn_export.targets.onnx_target import write_onnx
from vprsnn_export.trainer.pipeline import train_and_calibrate


def shared_data(name: str) -> Path:
    """``shared/data/<name>`` beside the repository or beside one of its parents (a worktree sits deeper)."""
    for folder in Path(__file__).resolve().parents[2].parents:
        if (folder / "shared/data" / name).is_dir():
            return folder / "shared/data" / name
    return Path(__file__).resolve().parents[3] / "shared/data" / name


NORDLAND = shared_data("nordland_64x32_summer_winter")
TINY = {"encoder.timesteps": 40, "train.epochs": 2, "network.n_neurons": 16}


def write_models(folder: Path, ckpt: Checkpoint, data: Dataset) -> tuple[Path, Path, Path]:
    """A checkpoint, its 4-bit model and that model's ONNX graph in ``folder``."""
    net = save_checkpoint(folder / "net.npz", ckpt)
    model = deploy(ckpt, checkpoint_sha256(net), 4, reference_images={"summer": data.traversal("summer")})
    fixed = save_fixed_point(folder / "q4.npz", model)
    return net, fixed, write_onnx(model, folder / "q4.onnx")


def trained_models(folder: Path, data_source: str, places: str | None) -> tuple[Path, Path, Path]:
    """A tiny network trained on ``data_source`` and its models (:func:`write_models`)."""
    cfg = Config().replace(**TINY)
    data = load_dataset(data_source, ["summer", "winter"], cfg.preprocess, places=places)
    ckpt = train_and_calibrate(data, ["summer"], cfg, progress=False, selection={"subset": None, "places": places})
    return write_models(folder, ckpt, data)


def video(frames: list[np.ndarray], path: Path) -> Path:
    """An MJPEG .avi of greyscale frames (lossy: the frames differ slightly from the images)."""
    height, width = frames[0].shape
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (width, height), isColor=True)
    for frame in frames:
        writer.write(cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR))
    writer.release()
    return path


def localize(capsys, *argv) -> list[dict]:
    assert main(["localize", *map(str, argv), "--quiet"]) == 0
    return [json.loads(line) for line in capsys.readouterr().out.splitlines()]


def decisions(lines: list[dict]) -> list[tuple]:
    return [(d["frame"], d["place_id"], d["confidence"], d["accepted"]) for d in lines]


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory, trained):
    folder = tmp_path_factory.mktemp("localize")
    net, fixed, graph = write_models(folder, *trained)  # the session's network on 24 places (tests/conftest.py)
    frames = folder / "frames"
    frames.mkdir()
    grey = synthetic_route(24, ("winter",))["winter"]
    for index, image in enumerate(grey):  # natural order: f2 before f10
        cv2.imwrite(str(frames / f"f{index}.png"), image)
    return net, fixed, graph, frames, grey


def test_folder_stdin_and_backends(synthetic, capsys, monkeypatch):
    net, fixed, graph, frames, _ = synthetic
    integer = localize(capsys, fixed, "--frames", frames, "--k", "3", "--threshold", "0.5")
    assert [d["name"] for d in integer[:3]] == ["f0.png", "f1.png", "f2.png"] and len(integer) == 24
    assert set(integer[0]) == {"frame", "name", "place_id", "confidence", "accepted", "velocity", "latency_ms"}
    onnx = localize(capsys, fixed, "--frames", frames, "--k", "3", "--threshold", "0.5", "--onnx", graph)
    assert decisions(onnx) == decisions(integer)
    assert any(d["accepted"] for d in integer) and not all(d["accepted"] for d in integer)
    floating = localize(capsys, net, "--frames", frames, "--k", "3")
    assert len(floating) == 24 and not any(d["accepted"] for d in floating)  # no operating point: none accepted
    paths = "\n".join(str(frames / f"f{i}.png") for i in range(5)) + "\n\n"
    monkeypatch.setattr("sys.stdin", io.StringIO(paths))
    piped = localize(capsys, fixed, "--frames", "-", "--k", "3", "--threshold", "0.5")
    assert decisions(piped) == decisions(integer)[:5]


def test_calibrate_stores_the_operating_point_beside_the_model(synthetic, capsys):
    _, fixed, graph, frames, _ = synthetic
    assert main(["localize", str(fixed), "--calibrate", "winter", "--k", "3", "--precision", "1.0"]) == 0
    out = capsys.readouterr().out
    assert "precision 100.0 %" in out
    stored = json.loads(fixed.with_name("q4.operating-point.json").read_text())
    assert stored["options"]["ks"] == [3] and stored["precision"] == 1.0
    # the curve it was chosen from, beside it: its chosen point is the stored threshold, printed with its neighbours
    curve = json.loads(fixed.with_name("q4.operating-point.curve.json").read_text())
    assert curve["threshold"] == stored["threshold"] and curve["n_queries"] == 24
    points = curve["points"]
    chosen = [p for p in points if p["threshold"] == stored["threshold"]]
    assert len(chosen) == 1 and chosen[0]["precision"] == 1.0 and chosen[0]["recall"] == stored["recall"]
    lower = [p for p in points if p["threshold"] < stored["threshold"]]
    assert all(p["precision"] < 1.0 for p in lower)  # the lowest threshold that keeps precision 1.0
    assert [p["accepted"] for p in points] == sorted(p["accepted"] for p in points)
    assert fixed.with_name("q4.operating-point.curve.png").read_bytes().startswith(b"\x89PNG")
    marked = [line for line in out.splitlines() if "<- operating point" in line]
    assert len(marked) == 1 and marked[0].split()[0] == f"{stored['threshold']:.6f}"
    lines = localize(capsys, fixed, "--frames", frames, "--precision", "1.0", "--onnx", graph)
    assert all(d["accepted"] == (d["place_id"] is not None and d["confidence"] >= stored["threshold"]) for d in lines)
    accepted = [d for d in lines if d["accepted"]]
    assert accepted and all(d["place_id"] == d["frame"] for d in accepted)  # the synthetic frames are places 0..23
    assert main(["localize", str(fixed), "--frames", str(frames), "--k", "5"]) == 2
    assert "differs from the operating point" in capsys.readouterr().err


def test_a_stream_tracks_the_velocity_causally_and_refuses_smooth(synthetic, capsys):
    """localize's --velocity-search tracks (the first causal estimate); "smooth" waits for later frames."""
    _, fixed, _, frames, _ = synthetic
    search = ["--k", "3", "--velocity-search", "0.5:1.5:0.5", "--threshold", "0.5"]

    def answers(lines: list[dict]) -> list[tuple]:
        return [(d["frame"], d["place_id"], d["confidence"], d["accepted"], d["velocity"]) for d in lines]

    tracked = answers(localize(capsys, fixed, "--frames", frames, *search))
    assert tracked == answers(localize(capsys, fixed, "--frames", frames, *search, "--velocity-estimate", "track"))
    assert len({v for *_, v in tracked}) > 1  # the velocity is tracked, not fixed
    assert main(["localize", str(fixed), "--frames", str(frames), *search, "--velocity-estimate", "smooth"]) == 2
    assert "invalid choice" in capsys.readouterr().err  # not offered: its choices are the causal estimates


def test_bad_frames_are_one_line(synthetic, capsys, tmp_path):
    _, fixed, _, _, _ = synthetic
    (tmp_path / "notes.txt").write_text("x")
    for frames, message in (
        (tmp_path, "no image files"),
        (tmp_path / "notes.txt", "not a video"),
        (tmp_path / "x", "no such"),
    ):
        assert main(["localize", str(fixed), "--frames", str(frames)]) == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1


@pytest.mark.skipif(not NORDLAND.is_dir(), reason=f"the shared Nordland data is absent ({NORDLAND})")
def test_real_frames_from_a_folder_and_a_video(tmp_path, capsys):
    cfg = Config().replace(**TINY)
    data = load_dataset(str(NORDLAND), ["summer", "winter"], cfg.preprocess, places="100:12")
    ckpt = train_and_calibrate(data, ["summer"], cfg, progress=False, selection={"subset": None, "places": "100:12"})
    net, fixed, graph = write_models(tmp_path, ckpt, data)
    manifest = read_manifest(NORDLAND)
    frames = tmp_path / "winter"
    frames.mkdir()
    grey = []
    for place in range(100, 112):
        source = NORDLAND / manifest.rows[place][1]["winter"]
        shutil.copy(source, frames / f"frame{place - 100}.png")
        grey.append(cv2.imread(str(source), cv2.IMREAD_GRAYSCALE))
    clip = video(grey, tmp_path / "winter.avi")
    for source in (frames, clip):
        lines = {
            name: localize(capsys, model, "--frames", source, "--k", "3", "--threshold", "0.5", *extra)
            for name, model, extra in (("float", net, ()), ("integer", fixed, ()), ("onnx", fixed, ("--onnx", graph)))
        }
        assert all(len(found) == 12 for found in lines.values())
        assert decisions(lines["integer"]) == decisions(lines["onnx"])
        assert all(d["place_id"] is None or 100 <= d["place_id"] < 112 for d in lines["float"])
    assert lines["integer"][0]["name"] == "winter.avi#0"


# ------------------------------------------------------ outputs never overwrite inputs; tampered points (issue 31)


def test_calibration_and_predictions_refuse_to_overwrite_an_input(tmp_path, capsys, image_route):
    places = image_route(tmp_path / "data") / "places.csv"
    subset = places.with_name("subset.csv")
    net, fixed, _ = trained_models(tmp_path, str(places), None)
    before = {path: path.read_bytes() for path in (places, subset, net, fixed)}
    data = ["--data", str(places), "--subset", str(subset)]
    for model, output in ((fixed, fixed), (net, net), (fixed, places), (fixed, subset)):
        argv = ["localize", str(model), "--calibrate", "winter", "--precision", "0.5", "--operating-point", str(output)]
        assert main([*argv, *data, "--quiet"]) == 2
        err = capsys.readouterr().err
        assert "one of this command's input files" in err and len(err.strip().splitlines()) == 1
    for output in (places, subset):
        argv = ["evaluate", str(net), "--query", "winter", *data, "--predictions", str(output), "--quiet"]
        assert main(argv) == 2
        assert "one of this command's input files" in capsys.readouterr().err
    assert {path: path.read_bytes() for path in before} == before


def test_a_killed_runs_temp_file_is_removed_by_the_next_run_and_a_second_writer_is_refused(synthetic, tmp_path, capsys):
    from vprsnn_export.io.fileio import output_lock

    _, fixed, _, _, _ = synthetic
    point = tmp_path / "point.json"
    stale = tmp_path / ".point.json.abcd1234.tmp"  # what atomic_write leaves when killed mid-write
    stale.write_text("{")
    argv = ["localize", str(fixed), "--calibrate", "winter", "--precision", "0.5", "--operating-point", str(point)]
    assert main([*argv, "--quiet"]) == 0
    assert point.is_file() and not stale.exists()
    with output_lock(point):  # another run is writing it now
        assert main([*argv, "--quiet"]) == 2
    assert "another vprsnn-export run is writing it" in capsys.readouterr().err
    predictions = tmp_path / "p.csv"
    with output_lock(predictions):
        assert main(["evaluate", str(synthetic[0]), "--query", "winter", "--predictions", str(predictions)]) == 2
    assert "another vprsnn-export run is writing it" in capsys.readouterr().err and not predictions.exists()


def test_an_operating_point_that_accepts_nothing_is_not_written(tmp_path, capsys):
    cfg = Config().replace(**{"encoder.timesteps": 8, "train.epochs": 0, "network.n_neurons": 2})
    data = load_dataset("synthetic:12", ["summer", "winter"], cfg.preprocess)
    ckpt = train_and_calibrate(data, ["summer"], cfg, progress=False, selection={"subset": None, "places": None})
    net = save_checkpoint(tmp_path / "weak.npz", ckpt)
    point = tmp_path / "weak.json"
    argv = ["localize", str(net), "--calibrate", "winter", "--precision", "1.0", "--operating-point", str(point)]
    assert main([*argv, "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "accepts nothing is not written" in err[0] and not point.exists()
    assert not list(tmp_path.glob("weak.curve.*"))  # nor the curve of a point that is not written


@pytest.mark.parametrize(
    "field, value",
    [
        ("threshold", -1),
        ("threshold", 0),
        ("threshold", "NaN"),
        ("threshold", "0.5"),
        ("threshold", True),
        ("precision_target", 2),
        ("recall", -0.1),
        ("n_queries", -3),
        ("match_window", 1.5),
    ],
)
def test_a_tampered_operating_point_is_refused_on_load(synthetic, tmp_path, capsys, field, value):
    _, fixed, _, frames, _ = synthetic
    point = tmp_path / "point.json"
    argv = ["localize", str(fixed), "--calibrate", "winter", "--precision", "0.5", "--operating-point", str(point)]
    assert main([*argv, "--quiet"]) == 0
    text = point.read_text()
    data = json.loads(text)
    data[field] = value
    point.write_text(json.dumps(data).replace('"NaN"', "NaN"))
    capsys.readouterr()
    assert main(["localize", str(fixed), "--frames", str(frames), "--operating-point", str(point), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "tampered or corrupt operating point" in err[0] and field in err[0]
    point.write_text("[" * 5000 + "]" * 5000)
    assert main(["localize", str(fixed), "--frames", str(frames), "--operating-point", str(point), "--quiet"]) == 2
    assert "corrupt operating point" in capsys.readouterr().err


def test_a_cropped_or_rescaled_stream_is_refused_before_any_decision(synthetic, tmp_path, capsys):
    _, fixed, _, _, grey = synthetic
    for label, frame in (("cropped", grey[0][:-1, :-1]), ("rescaled", cv2.resize(grey[0], (128, 64)))):
        folder = tmp_path / label
        folder.mkdir()
        cv2.imwrite(str(folder / "f0.png"), frame)
        capsys.readouterr()
        assert main(["localize", str(fixed), "--frames", str(folder), "--threshold", "0.5", "--quiet"]) == 2
        out, err = capsys.readouterr()
        assert out == "" and len(err.strip().splitlines()) == 1
        assert "the model's reference images are 64x32: a cropped or rescaled stream is refused" in err
