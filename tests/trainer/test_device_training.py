"""The torch training path (any GPU, or compiled=False): all modules of a batch in one train_batch call.

``train_batch`` then runs one batched matmul per step over (modules, batch, ...), so a GPU sees
one launch sequence per step for the whole ensemble, never a Python loop over modules.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vprsnn_export.config import preset
from vprsnn_export.trainer import batched
from vprsnn_export.trainer.batched import module_training_rows, train_modules
from vprsnn_export.trainer.train import Presentation

SMALL = {"network.n_neurons": 12, "encoder.timesteps": 10, "train.epochs": 2, "train.batch_size": 8}
DEVICES = [
    "cpu",
    pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="torch sees no CUDA GPU")),
]


pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


@pytest.mark.parametrize("device", DEVICES)
def test_one_train_batch_call_per_batch_for_all_modules(device, monkeypatch):
    cfg = preset("paper").replace(**SMALL, **{"train.module_size": 16})
    images = np.random.default_rng(2).random((64, 784)).astype(np.float32)
    presentations = [Presentation("summer", p) for p in range(64)]
    rows = module_training_rows(64, 16, 1)  # four modules of 16 rows: two batches of 8 per epoch
    calls: list[int] = []
    real = batched.train_batch

    def counted(weights, theta, spikes, cfg, *, compiled=True):
        calls.append(int(weights.shape[0]))
        return real(weights, theta, spikes, cfg, compiled=compiled)

    monkeypatch.setattr(batched, "train_batch", counted)
    trained = train_modules(
        images, presentations, rows, cfg, device=torch.device(device), progress=False, compiled=False
    )
    assert calls == [4] * (2 * 2)  # epochs x batches, every call with all four modules
    assert trained.weights.shape == (784, 4 * 12) and torch.isfinite(trained.weights).all()
