"""The weight-histogram plot's float line is a share of weights (<= 1), comparable to the level bars."""

import numpy as np

from vprsnn_export.runtime.report.plots import window_share


def test_a_peaked_histogram_gives_shares_not_densities():
    edges = np.linspace(0.0, 1.0, 65)
    counts = np.zeros(64)
    counts[0] = 900.0  # most weights in one narrow bin near 0: a density of 0.9 * 64 = 57.6 there
    counts[40] = 100.0
    for levels in (1, 3, 15, 255):
        x = np.linspace(0.0, 1.0, 401)
        share = window_share(edges, counts, x, 1 / levels)
        assert share.max() <= 1.0 + 1e-12
        at_levels = window_share(edges, counts, np.arange(levels + 1) / levels, 1 / levels)
        assert np.isclose(at_levels.sum(), 1.0)  # every weight rounds to exactly one level
    assert np.isclose(window_share(edges, counts, np.array([0.0]), 1 / 3)[0], 0.9)
