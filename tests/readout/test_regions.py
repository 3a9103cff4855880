"""Region regularisation of an ensemble: o_i, the hyperactive mask, silencing, per-module accuracy."""

import numpy as np
import pytest
from scipy import sparse

from vprsnn_export.config import Config
from vprsnn_export.data.truth import EXACT, GroundTruth
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.network.modules import module_regions
from vprsnn_export.readout.assignment import standard_scores
from vprsnn_export.readout.regions import (
    ModuleLayout,
    hyperactive_neurons,
    module_accuracy,
    module_layout,
    outside_involvement,
    region_weighting,
    regularise,
    silenced_counts,
)
from vprsnn_export.readout.scoring import Readout
from vprsnn_export.readout.sequence import SequenceOptions

# 2 modules x 2 neurons, 6 places: module 0 owns places 0-2, module 1 places 3-5.
SR = np.array(
    [
        [5, 1, 0, 0, 0, 0],  # module 0, fires only in its region: o = 0
        [3, 0, 0, 2, 1, 1],  # module 0, fires for all 3 places outside: o = 1
        [0, 0, 0, 4, 0, 0],  # module 1, only inside: o = 0
        [1, 0, 0, 0, 2, 0],  # module 1, 1 of 3 places outside: o = 1/3
    ]
)
REGIONS = module_regions(6, 3)


def layout(rho: float) -> ModuleLayout:
    return ModuleLayout(REGIONS, 2, rho)


def test_outside_involvement_by_hand():
    np.testing.assert_allclose(outside_involvement(SR, REGIONS, 2), [0.0, 1.0, 0.0, 1 / 3])


@pytest.mark.parametrize(
    ("rho", "silent"),
    [(1.0, [0, 0, 0, 0]), (0.5, [0, 1, 0, 0]), (0.3, [0, 1, 0, 1]), (0.0, [0, 1, 0, 1])],
)
def test_hyperactive_neurons_exceed_rho(rho, silent):
    np.testing.assert_array_equal(hyperactive_neurons(SR, layout(rho)), np.array(silent, dtype=bool))


def test_region_weighting_scales_the_outside():
    np.testing.assert_array_equal(region_weighting(SR, REGIONS, 2, 1.0), SR)
    region_only = region_weighting(SR, REGIONS, 2, 0.0)
    np.testing.assert_array_equal(region_only[:2, 3:], 0)
    np.testing.assert_array_equal(region_only[2:, :3], 0)
    np.testing.assert_array_equal(region_only[:2, :3], SR[:2, :3])
    half = region_weighting(SR, REGIONS, 2, 0.5)
    assert half[1, 3] == 1.0 and half[1, 0] == 3.0 and half[3, 0] == 0.5
    with pytest.raises(ValueError, match="outside_weight"):
        region_weighting(SR, REGIONS, 2, -0.5)


def test_regularise_weights_then_silences_from_the_raw_responses():
    sq = np.ones((2, 4))
    out_sr, out_sq = regularise(SR, sq, ModuleLayout(REGIONS, 2, 0.5, 0.0))
    expected = region_weighting(SR, REGIONS, 2, 0.0)
    expected[1] = 0  # o_1 = 1 > 0.5, measured on S^R before the outside is scaled away
    np.testing.assert_array_equal(out_sr, expected)
    np.testing.assert_array_equal(out_sq[:, 1], 0)


def test_single_network_is_never_changed():
    sr = np.array([[1, 2, 3], [0, 0, 4]])
    one = ModuleLayout(module_regions(3, 0), 2, 0.0, 0.0)
    assert not hyperactive_neurons(sr, one).any()
    sq = np.array([[1, 0], [2, 3]])
    out_sr, out_sq = regularise(sr, sq, one)
    np.testing.assert_array_equal(out_sr, sr)
    np.testing.assert_array_equal(out_sq, sq)


def test_silencing_zeroes_the_column_without_touching_the_input():
    sq = sparse.csr_array(np.arange(8).reshape(2, 4) + 1.0)
    before = sq.toarray()
    out = silenced_counts(sq, np.array([False, True, False, False])).toarray()
    assert not out[:, 1].any()
    np.testing.assert_array_equal(np.delete(out, 1, axis=1), np.delete(before, 1, axis=1))
    np.testing.assert_array_equal(sq.toarray(), before)


def test_sparse_and_dense_calibrations_regularise_alike():
    sq = np.arange(8).reshape(2, 4) % 3
    dense = regularise(SR, sq, ModuleLayout(REGIONS, 2, 0.5, 0.25))
    stored = regularise(sparse.csr_array(SR), sparse.csr_array(sq), ModuleLayout(REGIONS, 2, 0.5, 0.25))
    assert all(sparse.issparse(part) for part in stored) and not any(sparse.issparse(part) for part in dense)
    for a, b in zip(dense, stored, strict=True):
        assert a.tobytes() == b.toarray().tobytes()
    assert (
        hyperactive_neurons(sparse.csr_array(SR), layout(0.5)).tolist() == hyperactive_neurons(SR, layout(0.5)).tolist()
    )


def test_queries_do_not_decide_who_is_silenced():
    rng = np.random.default_rng(0)
    for _ in range(3):
        sq = rng.integers(0, 5, size=(7, 4))
        sr_out, _ = regularise(SR, sq, layout(0.5))
        np.testing.assert_array_equal(sr_out.any(axis=1), [True, False, True, True])


def test_layout_shape_mismatch_is_an_error():
    with pytest.raises(ValueError, match="module layout"):
        outside_involvement(SR[:3], REGIONS, 2)
    with pytest.raises(ValueError, match="hyperactive_share"):
        hyperactive_neurons(SR, layout(1.5))


def test_rho_one_gives_exactly_the_unregularised_rows():
    rng = np.random.default_rng(1)
    sr = rng.integers(0, 4, size=(8, 12)) * (rng.random((8, 12)) < 0.4)
    sq = rng.integers(0, 6, size=(12, 8)) * (rng.random((12, 8)) < 0.5)
    ids = np.arange(12)
    options = SequenceOptions(ks=(1, 3))
    plain = Readout(sr, 0.1, options).rows(sq, ids, ids)
    assert Readout(sr, 0.1, options, ModuleLayout(module_regions(12, 3), 2, 1.0)).rows(sq, ids, ids) == plain
    silenced = Readout(sr, 0.1, options, ModuleLayout(module_regions(12, 3), 2, 0.0)).rows(sq, ids, ids)
    assert len(silenced) == len(plain)


def test_silenced_neurons_do_not_vote():
    sq = np.array([[0, 9, 1, 0]])  # neuron 1 (hyperactive) would vote for place 0
    sr_out, sq_out = regularise(SR, sq, layout(0.5))
    assert standard_scores(sr_out, sq_out)[0].tolist() == [0, 0, 0, 1, 0, 0]  # only neuron 2 votes
    assert standard_scores(SR, sq)[0, 0] == 9


def test_module_layout_from_config():
    cfg = Config().replace(**{"train.module_size": 100, "network.n_neurons": 10, "assignment.hyperactive_share": 0.3})
    lay = module_layout(cfg, 250)
    assert lay.group == 10 and lay.hyperactive_share == 0.3 and lay.n_neurons == 30 and lay.outside_weight == 0.0
    np.testing.assert_array_equal(lay.regions, [[0, 100], [100, 200], [200, 250]])
    assert module_layout(cfg, 250, 1.0).hyperactive_share == 1.0


@pytest.mark.parametrize("key", ["assignment.hyperactive_share", "assignment.outside_weight"])
@pytest.mark.parametrize("value", [-0.1, 1.5, float("nan")])
def test_config_refuses_values_outside_the_unit_interval(key, value):
    with pytest.raises(InvalidValueError, match=key):
        Config().replace(**{key: value})


def test_module_accuracy_counts_each_region():
    reference = np.arange(10, 16)  # place ids 10..15, regions of 3
    queries = np.array([10, 11, 12, 13, 14, 15, 99])  # 99 is no reference place: left out
    pred = np.array([0, 4, -1, 3, 1, 5, 2])
    correct = np.array([True, False, False, True, False, True, False])
    rows = module_accuracy(pred, correct, reference, module_regions(6, 3), *EXACT.first_true(reference, queries))
    assert [(r.first_place, r.last_place, r.n_queries) for r in rows] == [(10, 12, 3), (13, 15, 3)]
    assert rows[0].accuracy == pytest.approx(1 / 3) and rows[0].in_region == pytest.approx(1 / 3)
    assert rows[1].accuracy == pytest.approx(2 / 3) and rows[1].in_region == pytest.approx(2 / 3)
    assert rows[0].to_dict()["module"] == 0


def test_module_accuracy_follows_the_ground_truth_that_scored_the_queries():
    """Issue 45: with a ground truth a query belongs to the module of its first true reference, not to j // P."""
    reference = np.arange(6)  # reference place ids 0..5, regions of 3
    queries = np.arange(5)  # query ids 0..4 of another traversal
    truth = np.zeros((6, 5), dtype=bool)  # GT[reference id, query id]
    truth[[3, 4, 5, 0, 1], [0, 1, 2, 3, 4]] = True  # queries 0-2 are places 3-5, queries 3-4 are places 0-1
    truth[2, 4] = True  # query 4 also matches place 2 (module 0 either way)
    pred = np.array([3, 0, 5, 0, 2])  # right, wrong (module 0), right, right, right
    correct = truth[pred, queries]
    regions = module_regions(6, 3)
    rows = module_accuracy(pred, correct, reference, regions, *GroundTruth(truth).first_true(reference, queries))
    assert [r.n_queries for r in rows] == [2, 3] and sum(r.n_queries for r in rows) == len(queries)
    assert rows[0].accuracy == 1.0 and rows[1].accuracy == pytest.approx(2 / 3)
    assert rows[1].in_region == pytest.approx(2 / 3)  # query 1 was sent to module 0
    by_index = module_accuracy(pred, correct, reference, regions, *EXACT.first_true(reference, queries))
    assert [r.n_queries for r in by_index] == [3, 2]  # what the index rule said: the wrong modules
    unmatched = truth.copy()
    unmatched[:, 0] = False  # a query no reference matches is left out
    assert (
        sum(
            r.n_queries
            for r in module_accuracy(
                pred, correct, reference, regions, *GroundTruth(unmatched).first_true(reference, queries)
            )
        )
        == 4
    )
