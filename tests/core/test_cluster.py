"""The --cluster addresses, and tasks mapped here (no cluster) in order with their timings."""

from __future__ import annotations

import pytest

from vprsnn_export.cluster import Cluster, TaskTiming, map_tasks, parse_cluster
from vprsnn_export.errors import InvalidValueError


def test_tasks_without_a_cluster_run_here_in_order():
    timing: list[TaskTiming] = []
    assert map_tasks(None, pow, [(2, 3), (3, 2), (5, 0)], timing=timing) == [8, 9, 1]
    assert len(timing) == 1 and len(timing[0].task_seconds) == 3 and timing[0].wall_seconds >= 0


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("local", Cluster("local", None)),
        ("local:2", Cluster("local", 2)),
        ("ray://head:10001", Cluster("ray://head:10001")),
    ],
)
def test_cluster_addresses_parse(text, expected):
    assert parse_cluster(text) == expected


@pytest.mark.parametrize("text", ["", "ray", "local:0", "local:x", "ray://head", "http://head:1"])
def test_bad_cluster_addresses_name_the_option(text):
    with pytest.raises(InvalidValueError, match="--cluster"):
        parse_cluster(text)


def test_more_threads_per_task_than_local_worker_slots_is_refused():
    assert parse_cluster("local:2", threads=2) == Cluster("local", 2, 2)
    with pytest.raises(InvalidValueError, match="--threads 3"):
        parse_cluster("local:2", threads=3)


def test_a_bar_counts_the_finished_tasks(capsys):
    assert map_tasks(None, pow, [(2, 3), (3, 2)], progress="modules") == [8, 9]
    assert "modules" in capsys.readouterr().err
    assert map_tasks(None, pow, [(2, 3)]) == [8]
    assert capsys.readouterr().err == ""  # no description: no bar
