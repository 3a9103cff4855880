"""Cost per query (network/cost.py) on tiny hand-computed cases."""

import numpy as np
import pytest

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.network.cost import nonzero_fan_out, prefix_sums, query_cost


def spikes_2x3x4() -> np.ndarray:
    """Two queries, three steps, four inputs. Query 0: 1, 2, 0 spikes per step; query 1: 4, 0, 1."""
    s = np.zeros((2, 3, 4), dtype=np.uint8)
    s[0, 0, 0] = 1
    s[0, 1, [1, 2]] = 1
    s[1, 0, :] = 1
    s[1, 2, 3] = 1
    return s


def test_counts_by_hand_with_every_input_reaching_every_neuron():
    cost = query_cost(spikes_2x3x4(), neurons=10, places=5)
    assert cost.input_spikes.tolist() == [3, 5]
    assert cost.steps.tolist() == [3, 3]
    assert cost.synaptic_events.tolist() == [30, 50]  # spikes x 10 neurons
    assert cost.neuron_updates.tolist() == [30, 30]  # 3 steps x 10 neurons
    # no images: the inputs that spiked stand in for the non-zero ones (3 and 4) x 5 places
    assert cost.template_macs.tolist() == [15, 20]
    summary = cost.summary()
    assert (summary.synaptic_events, summary.template_macs, summary.steps) == (40.0, 17.5, 3.0)
    assert (summary.snn_weights, summary.template_weights) == (40, 20)
    assert summary.event_ratio == pytest.approx(40 / 17.5)
    assert "40 synaptic events" in summary.line() and "18 multiply-adds" in summary.line()


def test_an_early_stop_counts_only_the_steps_used():
    cost = query_cost(spikes_2x3x4(), neurons=10, places=5, steps=np.array([1, 2]))
    assert cost.input_spikes.tolist() == [1, 4]
    assert cost.synaptic_events.tolist() == [10, 40]
    assert cost.neuron_updates.tolist() == [10, 20]
    assert query_cost(spikes_2x3x4(), neurons=1, places=1, steps=np.array([0, 0])).input_spikes.tolist() == [0, 0]


def test_per_input_fan_out_and_template_on_images():
    weights = np.array([[1.0, 0.0], [0.5, 0.5], [0.0, 0.0], [2.0, 1.0]])
    fan = nonzero_fan_out(weights)
    assert fan.tolist() == [1, 2, 0, 2]
    images = np.array([[0.1, 0.0, 0.0, 0.3], [0.0, 0.0, 0.0, 0.0]])
    cost = query_cost(spikes_2x3x4(), neurons=2, places=7, fan_out=fan, images=images)
    # query 0: input 0 (f 1) + inputs 1, 2 (f 2 + 0) = 3; query 1: 1 + 2 + 0 + 2 + input 3 again (2) = 7
    assert cost.synaptic_events.tolist() == [3, 7]
    assert cost.template_macs.tolist() == [14, 0]


def test_prefix_sums_reads_the_cumulative_sum_at_each_stop():
    a = np.array([[1, 2, 3], [4, 5, 6]])
    assert prefix_sums(a, np.array([0, 3])).tolist() == [0, 15]
    assert prefix_sums(a, np.array([2, 1])).tolist() == [3, 4]


@pytest.mark.parametrize(
    ("kwargs", "word"),
    [
        ({"steps": np.array([4, 1])}, "steps"),
        ({"steps": np.array([1.0, 1.0])}, "steps"),
        ({"fan_out": np.array([1, 2])}, "fan_out"),
        ({"images": np.zeros((2, 3))}, "images"),
    ],
)
def test_bad_arguments_are_named(kwargs, word):
    with pytest.raises(InvalidValueError, match=word):
        query_cost(spikes_2x3x4(), neurons=2, places=1, **kwargs)


def test_spikes_must_be_three_dimensional_integers():
    with pytest.raises(InvalidValueError, match="spikes"):
        query_cost(np.zeros((2, 3)), neurons=1, places=1)
    with pytest.raises(InvalidValueError, match="spikes"):
        query_cost(np.zeros((1, 2, 3), dtype=np.float32), neurons=1, places=1)
