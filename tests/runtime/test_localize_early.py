"""localize applies config.early like evaluate does (issue 45: the rule was silently not applied)."""

from __future__ import annotations

import dataclasses

import numpy as np

import vprsnn_export as vx
from vprsnn_export.readout.early import early_run


def test_a_localizer_decides_on_the_early_rules_counts(trained):
    ckpt, data = trained
    early = dataclasses.replace(ckpt, config=ckpt.config.replace(**{"early.spikes": 3}))
    inputs = data.traversal("winter")[:6]
    plain = vx.Localizer(ckpt, threshold=0.5)
    ruled = vx.Localizer(early, threshold=0.5)
    spikes = ruled.spikes(inputs, 0)
    counts = ruled.counts(inputs, 0)
    assert counts.sum(axis=1).max() <= 3  # the rule stops each frame at its third output spike
    assert not np.array_equal(counts, plain.counts(inputs, 0))
    network = vx.FloatNetwork.from_arrays(early.weights, early.thresholds, early.config, "cpu")
    expected = early_run(network.run, spikes, early.calibration, early.config, isolated=True)
    np.testing.assert_array_equal(counts, expected.counts)


def test_evaluate_with_the_early_rule_runs_each_query_once(trained, monkeypatch):
    """Issue 42: with config.early on, evaluate ran every query twice (a whole run, then the rule's chunks)."""
    from vprsnn_export.network.dynamics import FloatNetwork
    from vprsnn_export.runtime.evaluation import evaluate_float

    ckpt, data = trained
    early = dataclasses.replace(ckpt, config=ckpt.config.replace(**{"early.spikes": 3}))
    presented: list[int] = []
    original = FloatNetwork.run

    def counted(self, spikes, **kwargs):
        presented.append(int(spikes.shape[0]))
        return original(self, spikes, **kwargs)

    monkeypatch.setattr(FloatNetwork, "run", counted)
    result = evaluate_float(early, data.traversal("winter"), data.place_ids, "winter", vx.SequenceOptions())
    assert sum(presented) == len(data.place_ids)  # once each, in the rule's chunks
    assert result.query_counts.sum(axis=1).max() <= 3
    assert result.spike_stats.mean_candidates_per_step > 0  # the whole presentations' statistics are kept
