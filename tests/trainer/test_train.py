import numpy as np
import torch

from vprsnn_export.config import preset
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.trainer.calibrate import calibrate
from vprsnn_export.trainer.train import Presentation, train_network

SMALL = {"network.n_neurons": 16, "encoder.timesteps": 20, "train.epochs": 2, "train.batch_size": 4}


def _data(n=6):
    images = np.random.default_rng(1).random((n, 784)).astype(np.float32)
    return images, [Presentation("summer", i) for i in range(n)]


def test_same_seed_same_weights_and_different_seed_differs():
    cfg = preset("paper").replace(**SMALL)
    images, pres = _data()
    a = train_network(images, pres, cfg, device=torch.device("cpu"), progress=False)
    b = train_network(images, pres, cfg, device=torch.device("cpu"), progress=False)
    assert torch.equal(a.weights, b.weights) and torch.equal(a.thresholds, b.thresholds)
    c = train_network(images, pres, cfg.replace(seed=7), device=torch.device("cpu"), progress=False)
    assert not torch.equal(a.weights, c.weights)


def test_training_keeps_weights_bounded_and_columns_normalised():
    cfg = preset("paper").replace(**SMALL)
    images, pres = _data()
    net = train_network(images, pres, cfg, device=torch.device("cpu"), progress=False)
    assert net.weights.min() >= 0 and net.weights.max() <= cfg.stdp.w_max
    norms = torch.linalg.vector_norm(net.weights, dim=0)
    assert torch.allclose(norms, torch.ones_like(norms), atol=1e-5)
    assert len(net.history) == 2 and net.history[0]["spikes_per_presentation"] > 0


def test_calibration_sums_reference_traversals():
    cfg = preset("paper").replace(**SMALL)
    images, pres = _data(4)
    net = train_network(images, pres, cfg, device=torch.device("cpu"), progress=False)
    network = FloatNetwork.from_arrays(net.weights.numpy(), net.thresholds.numpy(), cfg, torch.device("cpu"))
    ids = np.arange(4)
    one = calibrate(network.counts, {"a": images}, ids, cfg)
    two = calibrate(network.counts, {"a": images, "b": images}, ids, cfg)
    assert one.shape == (16, 4) and one.sum() > 0
    assert two.sum() > one.sum()  # a second traversal (own presentation keys) adds spikes
