"""Outputs: what may be written, permissions, no temp files left, one line and exit 2 for a bad --out."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from vprsnn_export.cli import main
from vprsnn_export.io.fileio import (
    OutputError,
    atomic_write_text,
    check_output,
    output_lock,
    publish_folder,
    staging_folder,
)

TRAIN = ["train", "--data", "synthetic:8", "--reference", "summer", "--quiet", "--timesteps", "20", "--epochs", "1"]


def test_refuses_folders_special_files_links_and_empty_paths(tmp_path):
    (tmp_path / "folder").mkdir()
    target = tmp_path / "real.txt"
    target.write_text("x")
    (tmp_path / "link.txt").symlink_to(target)
    os.mkfifo(tmp_path / "pipe")
    for bad, message in (
        (tmp_path / "folder", "is a folder"),
        (tmp_path / "link.txt", "symbolic link"),
        (tmp_path / "pipe", "not a regular file"),
        ("", "empty output path"),
    ):
        with pytest.raises(OutputError, match=message):
            atomic_write_text(bad, "new")
    assert target.read_text() == "x"
    with pytest.raises(OutputError, match="--force"):
        check_output(target, overwrite=False)


def test_written_files_respect_the_umask_and_leave_no_temp_files(tmp_path):
    previous = os.umask(0o022)
    try:
        path = atomic_write_text(tmp_path / "a.txt", "hello")
    finally:
        os.umask(previous)
    assert (path.stat().st_mode & 0o777) == 0o644
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]


def test_unwritable_place_is_one_error():
    with pytest.raises(OutputError, match="cannot write here"):
        atomic_write_text("/proc/x.npz", "x")  # a place no user, root included, can create a file in


def test_train_checks_its_output_before_training(tmp_path, capsys):
    existing = tmp_path / "net.npz"
    existing.write_bytes(b"old")
    assert main([*TRAIN, "--out", str(existing)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "exists already" in err and existing.read_bytes() == b"old"
    assert main([*TRAIN, "--out", str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err
    assert main([*TRAIN, "--out", str(existing), "--force"]) == 0
    assert existing.read_bytes() != b"old"


def test_sigint_exits_130_with_one_line_and_no_temp_file(tmp_path):
    out = tmp_path / "net.npz"
    command = [sys.executable, "-m", "vprsnn_export", *TRAIN[:-4], "--timesteps", "300", "--epochs", "100000"]
    process = subprocess.Popen(
        [*command, "--out", str(out)],
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
        # a job started in the background inherits SIGINT ignored; a user's Ctrl-C reaches a foreground process
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    lock = tmp_path / ".net.npz.lock"  # taken by main() after the handlers are set, before the training
    began = time.monotonic()
    while not lock.exists() and process.poll() is None and time.monotonic() - began < 120:
        time.sleep(0.1)
    time.sleep(1)  # into the training
    try:
        process.send_signal(signal.SIGINT)
        _, err = process.communicate(timeout=120)
    finally:  # a run that outlives the test (a loaded machine) must not keep training
        process.kill()
    assert process.returncode == 130, err
    assert err.strip().splitlines()[-1] == "error: interrupted" and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_a_second_writer_to_the_same_output_stops_at_once(tmp_path, capsys):
    out = tmp_path / "net.npz"
    (tmp_path / ".net.npz.x1y2.tmp").write_bytes(b"left by a killed run")
    with output_lock(out):
        assert not (tmp_path / ".net.npz.x1y2.tmp").exists()
        with pytest.raises(OutputError, match="another vprsnn-export run"):
            with output_lock(out):
                pass
        assert main([*TRAIN, "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "another vprsnn-export run" in err
    assert list(tmp_path.iterdir()) == []  # the lock file goes with the lock
    with output_lock(out):
        pass


def test_a_lock_for_an_output_in_a_folder_not_made_yet(tmp_path):
    with output_lock(tmp_path / "new" / "deeper" / "net.npz"):
        assert [p.name for p in tmp_path.iterdir()] == [".net.npz.lock"]
    assert list(tmp_path.iterdir()) == []


def test_publish_folder_replaces_the_old_folder_whole(tmp_path):
    out = tmp_path / "deploy"
    out.mkdir()
    (out / "old.txt").write_text("old")
    staging = staging_folder(out)
    (staging / "new.txt").write_text("new")
    publish_folder(staging, out)
    assert [p.name for p in out.iterdir()] == ["new.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["deploy"]


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda d: "", "empty output path"),
        (lambda d: d / "notes.txt", "is not a folder"),
        (lambda d: d / "notes.txt" / "sub", "is not a folder"),
        (lambda d: d / "link", "symbolic link"),
        (lambda d: d / ("a" * 300), "too long"),
    ],
)
def test_folder_outputs_are_checked_before_any_work(tmp_path, capsys, make, message):
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "link").symlink_to(tmp_path / "notes.txt")
    out = make(tmp_path)
    assert main(["experiment", "assignment", "--quick", "--quiet", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
    assert (tmp_path / "notes.txt").read_text() == "x"


def test_train_never_overwrites_its_own_input(tmp_path, capsys):
    manifest = tmp_path / "subset.csv"
    manifest.write_text("place_id\n0\n1\n2\n")
    argv = [*TRAIN, "--subset", str(manifest), "--out", str(manifest), "--force"]
    assert main(argv) == 2
    assert "input files" in capsys.readouterr().err and manifest.read_text().startswith("place_id")


def plant_leftovers(folder):
    """What a run killed while writing inside ``folder`` leaves, named as the writers name it."""
    (folder / "plots").mkdir(parents=True, exist_ok=True)
    (folder / "exports").mkdir(exist_ok=True)
    planted = [
        tempfile.mkstemp(prefix=".model_8b.npz.", suffix=".tmp", dir=folder),
        tempfile.mkstemp(prefix=".report.json.", suffix=".tmp", dir=folder),
        tempfile.mkstemp(prefix=".accuracy.png.", suffix=".tmp", dir=folder / "plots"),
    ]
    for fd, _ in planted:
        os.close(fd)
    staging = staging_folder(folder / "exports" / "net")
    (staging / "half.onnx").write_bytes(b"half")
    return [Path(name) for _, name in planted] + [staging]


def test_leftovers_inside_an_output_folder_go_and_the_rest_stays(tmp_path):
    out = tmp_path / "out"
    leftovers = plant_leftovers(out)
    kept = [out / "notes.tmp", out / ".hidden.tmp", out / "plots" / "a.png", out / "model_8b.npz"]
    for path in kept:
        path.write_bytes(b"mine")
    with output_lock(out / "trained.npz"):  # another run (train --out DIR/trained.npz) writing inside the folder now
        fd, live = tempfile.mkstemp(prefix=".trained.npz.", suffix=".tmp", dir=out)
        os.close(fd)
        with output_lock(out):
            assert Path(live).exists()  # its writer holds its lock: not a leftover
            assert not any(path.exists() for path in leftovers)
            assert all(path.read_bytes() == b"mine" for path in kept)


@pytest.mark.parametrize("command", ["quantize", "verify"])
def test_the_next_run_removes_what_a_killed_run_left_in_its_output_folder(tmp_path, capsys, command, cli_checkpoint):
    ckpt = cli_checkpoint("synthetic:8", "--quiet", "--timesteps", "20", "--epochs", "1", "--threads", "1")
    out = tmp_path / "out"
    leftovers = plant_leftovers(out)
    if command == "quantize":
        argv = ["quantize", str(ckpt), "--bits", "8", "--out", str(out), "--quiet"]
    else:
        argv = ["verify", str(ckpt), "--query", "winter", "--bits", "8", "--report", str(out), "--quiet"]
    assert main([*argv, "--threads", "1"]) in (0, 1), capsys.readouterr().err  # verify: 1 when a check fails
    assert not any(path.exists() for path in leftovers)
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp") or ".staging-" in p.name]


def test_the_lock_holds_when_the_outputs_folder_appears_during_the_first_run(tmp_path):
    """Issue 45: run A locks new/dir/s.npz before new/dir exists, then creates it; run B, started after, must not
    get the lock (the lock beside the output would be another file for it)."""
    import subprocess
    import sys

    from vprsnn_export.io.fileio import output_lock

    target = tmp_path / "new" / "dir" / "s.npz"
    probe = f"from vprsnn_export.io.fileio import output_lock\nwith output_lock({str(target)!r}): print('got it')"
    with output_lock(target):
        target.parent.mkdir(parents=True)
        second = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
        assert "got it" not in second.stdout and "another vprsnn-export run is writing it now" in second.stderr
    again = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert "got it" in again.stdout
