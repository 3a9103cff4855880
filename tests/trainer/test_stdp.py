import numpy as np
import torch

from vprsnn_export.config import HomeostasisConfig, STDPConfig
from vprsnn_export.trainer.homeostasis import homeostasis_update
from vprsnn_export.trainer.stdp import apply_update, decay_trace, normalise_columns, stdp_delta


def test_trace_decay():
    x = decay_trace(torch.tensor([[2.0, 0.0]]), torch.tensor([[0.0, 1.0]]), tau=4.0)
    assert torch.allclose(x, torch.tensor([[1.5, 1.0]]))


def test_stdp_delta_by_hand():
    cfg = STDPConfig(a_plus=0.1, a_minus=0.01, w_max=1.0)
    w = torch.tensor([[0.5, 1.0], [0.0, 0.25]])  # (inputs=2, neurons=2)
    x = torch.tensor([[1.0, 2.0]])  # pre traces
    s = torch.tensor([[1.0, 0.0]])  # pre spikes
    y = torch.tensor([[0.0, 4.0]])  # post traces
    post = torch.tensor([[1.0, 0.0]])  # neuron 0 fired
    dw = stdp_delta(w, x, s, y, post, cfg)
    # potentiation only in column 0: A+ (1 - w_i0) x_i ; depression only in row 0: A- w_0j y_j
    expected = torch.tensor([[0.1 * 0.5 * 1.0 - 0.01 * 0.5 * 0.0, 0.0 - 0.01 * 1.0 * 4.0], [0.1 * 1.0 * 2.0, 0.0]])
    assert torch.allclose(dw, expected)


def test_soft_bound_stops_potentiation_at_w_max_and_depression_at_zero():
    cfg = STDPConfig(a_plus=0.5, a_minus=0.5, w_max=1.0)
    w = torch.tensor([[1.0], [0.0]])
    ones = torch.ones(1, 2)
    dw = stdp_delta(w, ones, ones, torch.ones(1, 1), torch.ones(1, 1), cfg)
    # w = w_max gets no potentiation (only depression); w = 0 gets no depression (only potentiation)
    assert torch.allclose(dw, torch.tensor([[-0.5], [0.5]]))


def test_update_clips_then_normalises_columns():
    cfg = STDPConfig(w_max=1.0)
    w = apply_update(torch.tensor([[0.9, 0.0], [0.5, 0.0]]), torch.tensor([[0.5, 0.3], [-1.0, 0.4]]), cfg)
    # clip -> [[1.0, 0.3], [0.0, 0.4]]; columns normalised to unit L2 norm
    assert torch.allclose(w, torch.tensor([[1.0, 0.6], [0.0, 0.8]]))
    assert torch.allclose(normalise_columns(torch.zeros(3, 2)), torch.zeros(3, 2))
    raw = apply_update(torch.tensor([[0.9]]), torch.tensor([[0.5]]), STDPConfig(weight_norm=False))
    assert torch.allclose(raw, torch.tensor([[1.0]]))


def test_homeostasis_direction_and_bounds():
    cfg = HomeostasisConfig(eta=0.1, r_target=0.01, theta_min=0.6, theta_max=100.0)
    theta = torch.tensor([1.0, 1.0, 0.6])
    rates = torch.tensor([0.51, 0.01, 0.0])
    new = homeostasis_update(theta, rates, cfg)
    assert new[0] > 1.0 and new[1] == 1.0 and new[2] == 0.6  # busy up, on-target unchanged, clamped
    assert torch.allclose(new[0], torch.tensor(1.05))
    off = homeostasis_update(theta, rates, HomeostasisConfig(enabled=False))
    assert torch.equal(off, theta)


def test_the_default_homeostasis_moves_thresholds_where_the_papers_text_rate_leaves_them(train_network):
    """eta is per batch: the default (1) spreads the trained thresholds; the text's 0.001 once per batch (the
    paper preset's) leaves every one within 0.002 of theta_init, the inert homeostasis of research log §12."""
    default, _ = train_network()
    text_rate, _ = train_network(**{"homeostasis.eta": 0.001})
    theta_init = default.config.network.theta_init
    assert default.config.homeostasis.eta == 1.0
    assert np.ptp(default.thresholds) > 0.05
    assert np.abs(text_rate.thresholds - theta_init).max() < 0.002


def test_a_network_learns_at_the_training_window_and_is_calibrated_at_the_encoders(train_network):
    """train.timesteps / train.rate_scale set the window STDP learns with; calibration (and every query) uses the
    encoder's: the weights equal those learnt with that encoder, the calibration differs, and a config that leaves
    them at 0 writes no such keys (files from before they existed stay byte-identical)."""
    long, _ = train_network(**{"encoder.timesteps": 40, "encoder.rate_scale": 0.25})
    split, _ = train_network(
        **{"encoder.timesteps": 10, "encoder.rate_scale": 0.5, "train.timesteps": 40, "train.rate_scale": 0.25}
    )
    assert np.array_equal(split.weights, long.weights) and np.array_equal(split.thresholds, long.thresholds)
    assert split.calibration.sum() <= 10 * split.calibration.shape[1] < long.calibration.sum()
    assert split.config.training_encoder == long.config.encoder
    assert "timesteps" not in long.config.to_dict()["train"]
    assert split.config.to_dict()["train"]["timesteps"] == 40
