"""--cluster against a hostile user (issue 31): a port out of range, an unreachable ray:// head."""

from __future__ import annotations

import socket
import time

import pytest

from vprsnn_export.cli import main
from vprsnn_export.cluster import CONNECT_TIMEOUT_S, parse_cluster
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
