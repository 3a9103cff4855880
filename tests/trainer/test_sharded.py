"""Modules trained and counted in tasks (here, or on a Ray cluster) gather into the single-process result."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy import sparse

from vprsnn_export.cluster import TaskTiming
from vprsnn_export.config import preset
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.trainer import calibrate as calibration
from vprsnn_export.trainer.batched import module_training_rows, train_modules
from vprsnn_export.trainer.calibrate import calibrate
from vprsnn_export.trainer.sharded import (
    calibrate_on_cluster,
    float_runs_on_cluster,
    group_inputs,
    module_groups,
    run_group,
    train_modules_on_cluster,
)
from vprsnn_export.trainer.train import Presentation

SMALL = {"network.n_neurons": 12, "encoder.timesteps": 20, "train.epochs": 2, "train.batch_size": 8}
CPU = torch.device("cpu")


pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def route(n_places: int, traversals: tuple[str, ...]) -> tuple[np.ndarray, list[Presentation]]:
    gen = np.random.default_rng(5)
    images = gen.random((len(traversals) * n_places, 784)).astype(np.float32)
    return images, [Presentation(name, 100 + p) for name in traversals for p in range(n_places)]


@pytest.mark.parametrize(("modules_per_task", "traversals"), [(1, ("summer",)), (2, ("spring", "fall"))])
def test_tasks_of_modules_gather_into_train_modules(modules_per_task, traversals):
    cfg = preset("paper").replace(**SMALL, **{"train.module_size": 20})
    images, presentations = route(50, traversals)
    rows = module_training_rows(50, 20, len(traversals))
    whole = train_modules(images, presentations, rows, cfg, device=CPU, progress=False)
    timing: list[TaskTiming] = []
    sharded = train_modules_on_cluster(
        images, presentations, rows, cfg, None, modules_per_task=modules_per_task, timing=timing
    )
    assert torch.equal(sharded.weights, whole.weights) and torch.equal(sharded.thresholds, whole.thresholds)
    strip = [{k: v for k, v in e.items() if k != "seconds"} for e in sharded.history]
    assert strip == [{k: v for k, v in e.items() if k != "seconds"} for e in whole.history]
    assert len(timing) == 1 and len(timing[0].task_seconds) == len(module_groups(3, modules_per_task))


def small_network(scope: str, isolation: bool | None = None):
    """Three modules of 12 neurons, random weights, 50 places in two traversals: (cfg, weights, thresholds, images)."""
    cfg = preset("paper").replace(**SMALL, **{"train.module_size": 20, "network.wta_scope": scope})
    if isolation is False:
        cfg = cfg.replace(**{"network.state_isolation": False})
    gen = np.random.default_rng(9)
    weights = (gen.random((784, 3 * 12)) * 0.2).astype(np.float32)
    thresholds = np.full(3 * 12, 2.0, dtype=np.float32)
    images = {"summer": gen.random((50, 784)).astype(np.float32), "winter": gen.random((50, 784)).astype(np.float32)}
    return cfg, weights, thresholds, images


@pytest.mark.parametrize(("scope", "isolation"), [("ensemble", None), ("module", None), ("ensemble", False)])
def test_float_runs_and_calibration_of_module_groups_equal_the_whole_network(scope, isolation):
    """One WTA per module: groups of modules per task; one WTA over the ensemble: slices of the presentations
    per task (one slice without state isolation); either way the whole network's counts, bit for bit."""
    cfg, weights, thresholds, images = small_network(scope, isolation)
    place_ids = np.arange(50)
    network = FloatNetwork.from_arrays(weights, thresholds, cfg, CPU)
    expected = calibrate(network.counts, images, place_ids, cfg)
    assert expected.sum() > 0
    got = calibrate_on_cluster(weights, thresholds, cfg, images, place_ids, None, modules_per_task=2)
    assert np.array_equal(got, expected) and got.flags.f_contiguous == expected.flags.f_contiguous
    runs = float_runs_on_cluster(weights, thresholds, cfg, {"winter": images["winter"]}, place_ids, "query", None)
    whole = network.run(query_spikes(images["winter"], place_ids, "winter", cfg))
    assert isinstance(runs["winter"].counts, sparse.csr_array)
    assert np.array_equal(runs["winter"].counts.toarray(), whole.counts.numpy())
    per_step = whole.counts.reshape(50, 3, 12).sum(dim=2)
    assert (int(per_step.sum(dim=1).max()) <= cfg.encoder.timesteps) == (scope == "ensemble")
    assert np.array_equal(runs["winter"].candidates_per_step, whole.candidates_per_step.numpy())


@pytest.mark.parametrize("scope", ["ensemble", "module"])
def test_a_long_routes_calibration_in_tasks_is_sparse_and_run_in_chunks(scope, monkeypatch):
    """Beyond ``dense_entries`` the gathered S^R stays CSR, and each task runs its presentations a chunk at a time
    (bounded memory on a worker): the integers of the whole network's S^R."""
    cfg, weights, thresholds, images = small_network(scope)
    place_ids = np.arange(50)
    whole = calibrate(FloatNetwork.from_arrays(weights, thresholds, cfg, CPU).counts, images, place_ids, cfg)
    runs = []
    real_run = FloatNetwork.run
    monkeypatch.setattr(
        FloatNetwork, "run", lambda self, spikes, **kw: runs.append(len(spikes)) or real_run(self, spikes, **kw)
    )
    monkeypatch.setattr(calibration, "SPIKES_PER_CHUNK", 7 * cfg.encoder.timesteps * cfg.network.n_inputs)
    got = calibrate_on_cluster(weights, thresholds, cfg, images, place_ids, None, modules_per_task=2, dense_entries=0)
    assert isinstance(got, sparse.csr_array) and got.dtype == np.int64
    assert np.array_equal(got.toarray(), whole)
    assert max(runs) == 7  # no task ran more than a chunk of presentations at once


def test_group_inputs_renumber_rows_into_the_group_images():
    images = np.arange(10, dtype=np.float32)[:, None]
    presentations = [Presentation("a", p) for p in range(10)]
    sub, subp, rows = group_inputs(images, presentations, [np.array([7, 2]), np.array([9])])
    assert sub[:, 0].tolist() == [2, 7, 9] and [p.place_id for p in subp] == [2, 7, 9]
    assert [r.tolist() for r in rows] == [[1, 0], [2]]


def test_a_task_without_presentations_returns_empty_counts():
    cfg, weights, thresholds, _ = small_network("ensemble")
    counts, candidates = run_group(weights, thresholds, cfg, np.zeros((0, 784), np.float32), np.arange(0), "w", "query")
    assert counts.shape == (0, 36) and counts.dtype == np.int64 and candidates.shape == (0, cfg.encoder.timesteps)
