"""Modules trained side by side are, bit for bit, each module trained alone with the same seed."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vprsnn_export.config import preset
from vprsnn_export.network.modules import module_regions
from vprsnn_export.trainer.batched import module_training_rows, train_modules
from vprsnn_export.trainer.train import Presentation, train_network

SMALL = {"network.n_neurons": 12, "encoder.timesteps": 20, "train.epochs": 2, "train.batch_size": 8}
CPU = torch.device("cpu")


pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def route(n_places: int, traversals: tuple[str, ...]) -> tuple[np.ndarray, list[Presentation]]:
    gen = np.random.default_rng(3)
    images = gen.random((len(traversals) * n_places, 784)).astype(np.float32)
    presentations = [Presentation(name, 100 + p) for name in traversals for p in range(n_places)]
    return images, presentations


def alone(images, presentations, rows, cfg, *, compiled: bool):
    return train_network(
        images[rows], [presentations[r] for r in rows], cfg, device=CPU, progress=False, compiled=compiled
    )


@pytest.mark.parametrize(
    ("compiled", "threads", "traversals"),
    [(True, 1, ("summer",)), (True, 2, ("summer",)), (False, 1, ("summer",)), (True, 2, ("spring", "fall"))],
)
def test_each_module_is_bit_for_bit_the_module_trained_alone(compiled, threads, traversals):
    cfg = preset("paper").replace(**SMALL, **{"train.module_size": 20})
    images, presentations = route(50, traversals)  # regions of 20, 20 and an unequal last one of 10
    rows = module_training_rows(50, 20, len(traversals))
    assert [len(r) for r in rows] == [20 * len(traversals)] * 2 + [10 * len(traversals)]
    together = train_modules(
        images, presentations, rows, cfg, device=CPU, progress=False, threads=threads, compiled=compiled
    )
    n = cfg.network.n_neurons
    assert together.weights.shape == (784, 3 * n) and together.thresholds.shape == (3 * n,)
    for m, module in enumerate(rows):
        single = alone(images, presentations, module, cfg, compiled=compiled)
        assert torch.equal(together.weights[:, m * n : (m + 1) * n], single.weights), f"module {m} weights"
        assert torch.equal(together.thresholds[m * n : (m + 1) * n], single.thresholds), f"module {m} thresholds"
    assert len(together.history) == 2 and len(together.history[0]["module_active_neurons"]) == 3


def test_one_module_is_train_network_with_the_same_history():
    cfg = preset("paper").replace(**SMALL)
    images, presentations = route(30, ("summer",))
    rows = module_training_rows(30, 0, 1)
    together = train_modules(images, presentations, rows, cfg, device=CPU, progress=False)
    single = train_network(images, presentations, cfg, device=CPU, progress=False)
    assert torch.equal(together.weights, single.weights) and torch.equal(together.thresholds, single.thresholds)
    strip = [{k: v for k, v in e.items() if k != "seconds"} for e in together.history]
    assert strip == [{k: v for k, v in e.items() if k != "seconds"} for e in single.history]


def test_module_rows_follow_the_regions_in_every_traversal():
    rows = module_training_rows(5, 2, 2)
    assert [r.tolist() for r in rows] == [[0, 1, 5, 6], [2, 3, 7, 8], [4, 9]]
    assert len(rows) == len(module_regions(5, 2))


@pytest.mark.parametrize("compiled", [True, False])
def test_modules_learn_at_the_training_window_not_the_deployed_one(compiled):
    """train.timesteps / train.rate_scale reach the compiled kernel and the torch loop alike (config.training_encoder)."""
    learnt = preset("paper").replace(**SMALL, **{"train.module_size": 20})
    split = learnt.replace(
        **{"encoder.timesteps": 5, "encoder.rate_scale": 0.5, "train.timesteps": 20, "train.rate_scale": 0.25}
    )
    images, presentations = route(40, ("summer",))
    rows = module_training_rows(40, 20, 1)
    runs = [
        train_modules(images, presentations, rows, cfg, device=CPU, progress=False, threads=1, compiled=compiled)
        for cfg in (learnt, split, learnt.replace(**{"encoder.timesteps": 5}))
    ]
    assert torch.equal(runs[0].weights, runs[1].weights) and torch.equal(runs[0].thresholds, runs[1].thresholds)
    assert not torch.equal(runs[0].weights, runs[2].weights)  # the window does matter to learning
