"""`train --cluster` and `evaluate --cluster` on Ray: the same checkpoint bytes and the same results."""

from __future__ import annotations

import json

import pytest
import ray
from scipy import sparse

from vprsnn_export.cli import main
from vprsnn_export.cluster import Cluster, map_tasks
from vprsnn_export.runtime import evaluation

TINY = ["--timesteps", "20", "--epochs", "2", "--neurons", "16", "--module-size", "10", "--seed", "4", "--quiet"]


def train(out, *extra: str) -> bytes:
    args = ["train", "--data", "synthetic:30", "--reference", "summer", "--out", str(out), *TINY, *extra]
    assert main([*args, "--threads", "1"]) == 0
    return out.read_bytes()


def evaluate(path, capsys, *extra: str) -> dict:
    assert main(["evaluate", str(path), "--query", "winter", "--json", "--quiet", "--threads", "1", *extra]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.fixture
def two_workers():
    """A local Ray runtime of two worker slots, started by the test (the commands join it)."""
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield
    ray.shutdown()


def test_train_and_evaluate_on_ray_equal_one_process(two_workers, tmp_path, capsys):
    alone = train(tmp_path / "alone.npz")
    sharded = train(tmp_path / "ray.npz", "--cluster", "local")
    assert sharded == alone  # three modules trained in three tasks: byte for byte the same file
    capsys.readouterr()
    here = evaluate(tmp_path / "alone.npz", capsys)
    there = evaluate(tmp_path / "alone.npz", capsys, "--cluster", "local")
    assert there["results"] == here["results"] and there["modules"] == here["modules"]
    assert there["spike_stats"] == here["spike_stats"]


def test_a_long_route_is_gathered_from_ray_as_sparse_counts_with_the_same_results(
    two_workers, tmp_path, capsys, monkeypatch
):
    """A long route (more queries x neurons than DENSE_COUNT_ENTRIES: here any) keeps the tasks' counts as CSR, as
    the local run does, and scores what one process scores."""
    train(tmp_path / "alone.npz")
    capsys.readouterr()
    here = evaluate(tmp_path / "alone.npz", capsys)
    monkeypatch.setattr(evaluation, "DENSE_COUNT_ENTRIES", 0)
    kinds, real = [], evaluation.read_out
    monkeypatch.setattr(
        evaluation,
        "read_out",
        lambda readout, counts, *a, **k: kinds.append(type(counts)) or real(readout, counts, *a, **k),
    )
    there = evaluate(tmp_path / "alone.npz", capsys, "--cluster", "local")
    assert kinds == [sparse.csr_array]
    assert there["results"] == here["results"] and there["modules"] == here["modules"]
    assert there["spike_stats"] == here["spike_stats"]


@pytest.mark.slow
def test_a_two_process_local_cluster_started_by_the_command_gives_the_same_bytes(tmp_path):
    assert not ray.is_initialized()
    alone = train(tmp_path / "alone.npz")
    assert train(tmp_path / "ray.npz", "--cluster", "local:2") == alone
    assert not ray.is_initialized()  # the command shut down the runtime it started


@pytest.mark.parametrize("address", ["nope", "local:0", "ray://head"])
def test_a_bad_cluster_address_is_one_line_and_exit_2(tmp_path, capsys, address):
    args = ["train", "--data", "synthetic:10", "--reference", "summer", "--out", str(tmp_path / "x.npz"), *TINY]
    assert main([*args, "--cluster", address]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --cluster") and not (tmp_path / "x.npz").exists()


def test_experiment_route_on_ray_trains_the_same_networks(two_workers, tmp_path, monkeypatch):
    """experiment --cluster: every network's modules train in Ray tasks; the cached checkpoints and the rows
    equal a single-process run of the same experiment (separate caches)."""
    rows = {}
    for name, extra in (("alone", []), ("ray", ["--cluster", "local"])):
        monkeypatch.setenv("VPRSNN_CACHE", str(tmp_path / f"cache-{name}"))
        out = tmp_path / name
        args = ["experiment", "route", "--quick", "--module-sizes", "12", "--seeds", "1", "--out", str(out)]
        assert main([*args, "--quiet", "--threads", "1", *extra]) == 0
        rows[name] = json.loads((out / "route_quick.json").read_text())["networks"][0]["rows"]
        checkpoints = sorted((tmp_path / f"cache-{name}").glob("route12-*.npz"))
        rows[name + "-bytes"] = [p.read_bytes() for p in checkpoints]
    assert rows["ray"] == rows["alone"] and rows["ray-bytes"] == rows["alone-bytes"]
    assert len(rows["ray-bytes"]) == 2  # the ensemble-WTA network and its module-WTA recount


def test_experiment_cluster_option_is_parsed_and_checked(capsys):
    assert main(["experiment", "route", "--quick", "--cluster", "nowhere"]) == 2
    assert "--cluster" in capsys.readouterr().err


def test_ray_tasks_show_a_bar_and_keep_their_order(two_workers, capsys):
    tasks = [(base, 2) for base in range(6)]
    assert map_tasks(Cluster("local", 2), pow, tasks, progress="modules on ray") == [b * b for b in range(6)]
    assert "modules on ray" in capsys.readouterr().err
