"""--cluster against a hostile user (issue 31): a port out of range, an unreachable ray:// head, a SIGKILL."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time

import pytest

from vprsnn_export.cli import main
from vprsnn_export.cluster import CONNECT_TIMEOUT_S, descendants, parse_cluster, process_table
from vprsnn_export.errors import InvalidValueError

TINY = ["--timesteps", "20", "--epochs", "1", "--neurons", "16", "--module-size", "10", "--quiet"]


@pytest.mark.parametrize("port", ["0", "65536", "99999"])
def test_a_port_out_of_range_is_refused(port):
    with pytest.raises(InvalidValueError, match="65535"):
        parse_cluster(f"ray://head:{port}")
    assert parse_cluster("ray://head:65535").address == "ray://head:65535"


def closed_port() -> int:
    """A local port nothing listens on (bound, then released)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_an_unreachable_head_is_one_line_within_the_connect_timeout(tmp_path, capsys):
    args = ["train", "--data", "synthetic:10", "--reference", "summer", "--out", str(tmp_path / "x.npz"), *TINY]
    began = time.monotonic()
    assert main([*args, "--cluster", f"ray://127.0.0.1:{closed_port()}"]) == 2
    assert time.monotonic() - began < CONNECT_TIMEOUT_S + 20  # Ray Client alone retries for 35 s
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --cluster ray://127.0.0.1:"), err
    assert "no Ray head answers" in err[0] and not (tmp_path / "x.npz").exists()


@pytest.mark.slow
def test_a_killed_command_leaves_no_ray_process(tmp_path):
    """SIGKILL of `train --cluster local:2` while its tasks run: every process it started ends (Ray's own
    fate sharing stops the raylet and workers, the watchdog its dashboard and runtime-env agents)."""
    out = tmp_path / "x.npz"
    args = ["train", "--data", "synthetic:30", "--reference", "summer", "--out", str(out), *TINY]
    command = [sys.executable, "-c", "from vprsnn_export.cli import main; main()", *args, "--epochs", "200"]
    child = subprocess.Popen(
        [*command, "--cluster", "local:2"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=tmp_path
    )
    started: dict[int, str] = {}
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # until the tasks run
            started = descendants(child.pid, process_table())
            if any("ray::_timed" in cmdline(pid) for pid in started):
                break
            time.sleep(0.5)
        assert any("raylet" in cmdline(pid) for pid in started), "the local cluster did not start"
        child.kill()
        child.wait()
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline and alive(started):
            time.sleep(0.5)
        left = alive(started)
        assert not left, f"still running after SIGKILL: {[cmdline(pid) for pid in left]}"
    finally:
        child.kill()
        for pid in alive(started):  # the test's own leftovers, by pid
            os.kill(pid, signal.SIGKILL)


def cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as handle:
            return handle.read().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def alive(started: dict[int, str]) -> list[int]:
    """Those of ``started`` still running (the same pid with the same start time)."""
    table = process_table()
    return [pid for pid, start in started.items() if table.get(pid, (0, ""))[1] == start]
