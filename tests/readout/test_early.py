"""Early decision (readout/early.py): hand-computed stops, the margin rule's guarantee, backends agree."""

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from vprsnn_export.config import EarlyConfig
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.readout.assignment import standard_assignment
from vprsnn_export.readout.early import (
    counts_until,
    early_decision,
    early_in_chunks,
    is_off,
    margin_stops,
    spike_stops,
    step_bound,
    stop_steps,
)

# four neurons voting for places 0, 0, 1, 2 (one WTA group of all four)
A = np.array([[1, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)


def raster_of(winners: list[list[int]], neurons: int = 4) -> np.ndarray:
    """(N, T, neurons) bool from each query's winner per step (-1: no spike)."""
    z = np.zeros((len(winners), len(winners[0]), neurons), dtype=bool)
    for q, row in enumerate(winners):
        for t, j in enumerate(row):
            if j >= 0:
                z[q, t, j] = True
    return z


def test_margin_stops_by_hand():
    # T = 6, c = 1. Query 0 votes 0,0,0,0,...: after t steps lead t, second 0: t > 6 - t first at t = 4.
    # Query 1 alternates places 0 and 1: lead - second <= 1, never > 6 - t before t = 6: runs all 6 steps.
    # Query 2 never spikes: T.
    z = raster_of([[0, 1, 0, 1, 0, 1], [0, 2, 1, 2, 0, 2], [-1] * 6])
    assert step_bound(A, 4) == 1.0
    assert margin_stops(z, A, 4).tolist() == [4, 6, 6]


def test_spike_rule_and_the_earliest_rule_wins():
    z = raster_of([[0, -1, 2, 3, -1, 1], [-1, -1, -1, -1, -1, 2]])
    assert spike_stops(z, 2).tolist() == [3, 6]
    assert spike_stops(z, 1).tolist() == [1, 6]
    both = EarlyConfig(margin=True, spikes=2)
    assert stop_steps(z, A, 4, both).tolist() == [3, 6]
    assert stop_steps(z, A, 4, EarlyConfig()).tolist() == [6, 6] and is_off(EarlyConfig())
    decision = early_decision(z, A, 4, EarlyConfig(spikes=2))
    assert decision.counts.tolist() == [[1, 0, 1, 0], [0, 0, 1, 0]]


def test_step_bound_sums_the_groups():
    assert step_bound(A, 2) == 2.0  # two groups of two, each can add 1 to some place per step
    assert step_bound(0.5 * A, 4) == 0.5
    with pytest.raises(InvalidValueError, match="groups"):
        step_bound(A, 3)


def test_counts_until_counts_the_steps_run():
    z = raster_of([[0, 1, 2, 3], [3, 3, 3, 3]])
    assert counts_until(z, np.array([2, 0])).tolist() == [[1, 1, 0, 0], [0, 0, 0, 0]]
    assert counts_until(z, np.array([4, 4])).tolist() == z.sum(axis=1).tolist()


def test_bad_raster_is_named():
    with pytest.raises(InvalidValueError, match="raster"):
        stop_steps(np.zeros((2, 3, 4), dtype=np.uint8), A, 4, EarlyConfig(margin=True))


@given(st.integers(0, 2**32 - 1), st.integers(1, 3))
def test_the_margin_rule_never_changes_the_standard_decision(seed, groups):
    """Random rasters with one spike per group per step: the Standard argmax at the stop is the one at T."""
    rng = np.random.default_rng(seed)
    n, timesteps, group, places = 12, 40, 4, 5
    neurons = groups * group
    sr = rng.integers(0, 5, (neurons, places))
    assignment = standard_assignment(sr)
    # a winner per group per step (or none), biased to one neuron so that some queries settle early
    favourite = rng.integers(0, group, (n, 1, groups))
    winners = np.where(
        rng.random((n, timesteps, groups)) < 0.7, favourite, rng.integers(-1, group, (n, timesteps, groups))
    )
    z = np.zeros((n, timesteps, neurons), dtype=bool)
    q, t, g = np.nonzero(winners >= 0)
    z[q, t, g * group + winners[q, t, g]] = True
    decision = early_decision(z, assignment, group, EarlyConfig(margin=True))
    full = z.sum(axis=1) @ assignment
    early = decision.counts @ assignment
    stopped = decision.steps < timesteps
    assert np.array_equal(np.argmax(early[stopped], axis=1), np.argmax(full[stopped], axis=1))
    assert np.array_equal(decision.counts, counts_until(z, decision.steps))


def test_chunks_give_the_same_decision():
    rng = np.random.default_rng(3)
    z = rng.random((10, 8, 4)) < 0.3
    rule = EarlyConfig(margin=True, spikes=5)
    whole = early_decision(z, A, 4, rule)
    chunked = early_in_chunks(lambda a, b: z[a:b], 10, A, 4, rule, chunk=3)
    assert np.array_equal(whole.steps, chunked.steps) and np.array_equal(whole.counts, chunked.counts)


@pytest.mark.usefixtures("one_thread")
def test_integer_simulator_reference_stepper_and_onnx_decide_alike(make_model, tmp_path):
    """The stop step and counts from each backend's raster are equal (their rasters are), and running only the
    first T_q steps gives the same counts (state isolation)."""
    from vprsnn_export.targets.intsim import IntegerNetwork
    from vprsnn_export.targets.onnx_session import OnnxBackend
    from vprsnn_export.targets.onnx_target import write_onnx
    from vprsnn_export.targets.reference_stepper import ReferenceStepper

    model = make_model(np.random.default_rng(11), bits=4, n_inputs=16, n_neurons=6)
    spikes = torch.from_numpy((np.random.default_rng(12).random((6, 20, 16)) < 0.3).astype(np.uint8))
    assignment = standard_assignment(model.calibration)
    rule = EarlyConfig(margin=True, spikes=6)
    backends = [
        IntegerNetwork(model, torch.device("cpu")),
        ReferenceStepper(model),
        OnnxBackend(write_onnx(model, tmp_path / "m.onnx", with_raster=True)),
    ]
    decisions = []
    for backend in backends:
        run = backend.run(spikes, record=True)
        assert run.raster is not None, backend.name
        decisions.append(early_decision(run.raster.numpy(), assignment, 6, rule))
    for other in decisions[1:]:
        assert np.array_equal(other.steps, decisions[0].steps) and np.array_equal(other.counts, decisions[0].counts)
    assert decisions[0].steps.min() < 20  # the rule fires on some query
    integer = backends[0]
    for q, steps in enumerate(decisions[0].steps):
        truncated = integer.run(spikes[q : q + 1, :steps]).counts.numpy()
        assert np.array_equal(truncated[0], decisions[0].counts[q])


@pytest.mark.usefixtures("one_thread")
def test_the_float_network_stopped_at_t_counts_what_its_early_decision_counts(small_config):
    """Float path: the decision from the recorded raster equals running only the first T_q steps."""
    from vprsnn_export.network.dynamics import FloatNetwork

    rng = np.random.default_rng(5)
    cfg = small_config(16, 6)
    network = FloatNetwork.from_arrays(
        rng.random((16, 6)).astype(np.float32), np.full(6, 1.5, np.float32), cfg, torch.device("cpu")
    )
    spikes = torch.from_numpy((rng.random((5, 20, 16)) < 0.3).astype(np.uint8))
    run = network.run(spikes, record=True)
    assignment = standard_assignment(rng.integers(0, 4, (6, 3)))
    decision = early_decision(run.raster.numpy(), assignment, 6, EarlyConfig(margin=True, spikes=4))
    assert decision.steps.min() < 20
    for q, steps in enumerate(decision.steps):
        assert np.array_equal(network.run(spikes[q : q + 1, :steps]).counts.numpy()[0], decision.counts[q])
