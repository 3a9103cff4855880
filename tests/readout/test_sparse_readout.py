"""The sparse readout (issue 43) against the dense formulas it replaced: S'' entry for entry, the Standard scores
exactly, the Weighted scores to the float sums' order, and every decision and metric row the same."""

from __future__ import annotations

import numpy as np
from scipy import sparse

from vprsnn_export.config import Config
from vprsnn_export.data.truth import MatchWindow
from vprsnn_export.readout.assignment import standard_scores, weighted_matrix, weighted_scores, wprob_distribution
from vprsnn_export.readout.scoring import Readout
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.readout.strategies import decide

from .test_blocks import route_counts


def dense_weighted_matrix(sr: np.ndarray, gamma: float) -> np.ndarray:
    """Eq. 9-10 on the whole (neurons, places) array, as the readout computed it before it became sparse."""
    omega = np.count_nonzero(sr > 0, axis=1).astype(np.float64)
    divisor = np.where(omega > gamma * sr.shape[1], omega, 1.0)
    rowsum = sr.sum(axis=1)
    return (sr / divisor[:, None]) * (sr / np.where(rowsum > 0, rowsum, 1.0)[:, None])


def dense_weighted_scores(sr: np.ndarray, sq: np.ndarray, gamma: float) -> np.ndarray:
    """Eq. 9-11 with dense BLAS products."""
    colsum = sr.sum(axis=0)
    penalty = ((sq > 0).astype(np.float64) @ sr) / np.where(colsum > 0, colsum, 1.0)
    return (sq @ dense_weighted_matrix(sr, gamma)) * penalty


def test_the_sparse_kernels_are_the_dense_formulas():
    sr, counts = (a.astype(np.float64) for a in route_counts(500, 400, seed=5))
    assert weighted_matrix(sr, 0.02).tobytes() == dense_weighted_matrix(sr, 0.02).tobytes()
    assert sparse.issparse(weighted_matrix(sparse.csr_array(sr), 0.02))
    assert standard_scores(sr, counts).tobytes() == standard_scores(sparse.csr_array(sr), counts).tobytes()
    best = sr.argmax(axis=1)
    expected = np.zeros((500, 500))
    np.add.at(expected.T, best[sr.sum(axis=1) > 0], counts.T[sr.sum(axis=1) > 0])
    np.testing.assert_array_equal(standard_scores(sr, counts), expected)
    new, old = weighted_scores(sr, counts, 0.02), dense_weighted_scores(sr, counts, 0.02)
    np.testing.assert_allclose(new, old, rtol=1e-13, atol=0)
    np.testing.assert_array_equal(
        decide(wprob_distribution(new), "wprob")[0], decide(wprob_distribution(old), "wprob")[0]
    )


def test_sparse_and_dense_inputs_give_the_same_columns_bit_for_bit():
    places = 640
    sr, counts = route_counts(places, places, seed=7)
    cfg = Config().replace(**{"train.module_size": 64, "network.n_neurons": 64})
    ids = np.arange(places)
    options = SequenceOptions(ks=(1, 5, 10))
    dense = Readout.of(sr, cfg, options).score(counts, ids, ids, MatchWindow(1))
    stored = Readout.of(sparse.csr_array(sr), cfg, options).score_in_blocks(
        sparse.csr_array(counts), ids, ids, MatchWindow(1), block=100
    )
    for a, b in zip(dense.columns, stored.columns, strict=True):
        assert a.index.tobytes() == b.index.tobytes() and a.confidence.tobytes() == b.confidence.tobytes()
        assert a.row == b.row


def test_a_frame_pushed_alone_gets_the_batch_distribution_bit_for_bit():
    places = 640
    sr, counts = route_counts(places, places, seed=11)
    cfg = Config().replace(**{"train.module_size": 64, "network.n_neurons": 64, "assignment.hyperactive_share": 0.005})
    readout = Readout.of(sr, cfg, SequenceOptions(ks=(1,)))
    assert readout.calibrated()[1] is not None and readout.calibrated()[1].any()  # some neurons silenced
    batch = readout.scores(counts)["wprob"]
    for j in range(0, places, 7):
        assert readout.wprob(counts[j]).tobytes() == batch[j].tobytes()
