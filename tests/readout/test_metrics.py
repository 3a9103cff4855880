"""Exact PR metrics for single-match VPR."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vprsnn_export.readout.metrics import is_correct, pr_curve, pr_metrics, predicted_place_ids

CONF = np.array([0.9, 0.8, 0.8, 0.5, 0.3])
CORRECT = np.array([1, 1, 0, 1, 0], dtype=bool)


def test_hand_computed_example() -> None:
    precision, recall, thresholds = pr_curve(CORRECT, CONF)
    # operating points: >=0.9: 1/1; >=0.8 (tie accepted together): 2/3; >=0.5: 3/4; >=0.3: 3/5
    np.testing.assert_allclose(thresholds, [0.9, 0.8, 0.5, 0.3])
    np.testing.assert_allclose(precision, [1, 2 / 3, 3 / 4, 3 / 5])
    np.testing.assert_allclose(recall, [1 / 5, 2 / 5, 3 / 5, 3 / 5])
    m = pr_metrics(CORRECT, CONF)
    assert m["n_queries"] == 5
    assert m["accuracy"] == pytest.approx(0.6)
    assert m["p_at_100r"] == pytest.approx(0.6)  # = accuracy with single-match
    assert m["r_at_100p"] == pytest.approx(1 / 5)  # the 0.8 tie cannot be split
    # AUC = 0.2*1 + 0.2*(2/3) + 0.2*(3/4) + 0*(3/5) = 29/60
    assert m["auc_pr"] == pytest.approx(29 / 60)


def test_order_of_queries_does_not_matter() -> None:
    perm = np.array([3, 0, 4, 2, 1])
    assert pr_metrics(CORRECT[perm], CONF[perm]) == pr_metrics(CORRECT, CONF)
    # swap which tied query is the correct one: result identical (ties never split)
    correct2 = CORRECT.copy()
    correct2[[1, 2]] = [False, True]
    assert pr_metrics(correct2, CONF) == pr_metrics(CORRECT, CONF)


def test_all_tied_and_no_matches() -> None:
    m = pr_metrics(np.array([True, True, False]), np.array([0.5, 0.5, 0.5]))
    assert m["r_at_100p"] == 0.0
    assert m["auc_pr"] == pytest.approx(2 / 3 * 2 / 3)
    # two no-matches (confidence 0, incorrect) after two confident correct queries
    m = pr_metrics(np.array([1, 1, 0, 0]), np.array([0.9, 0.7, 0.0, 0.0]))
    assert m["r_at_100p"] == pytest.approx(0.5)
    assert m["accuracy"] == pytest.approx(0.5)
    assert m["auc_pr"] == pytest.approx(0.5)


def test_perfect_and_hopeless() -> None:
    m = pr_metrics(np.ones(4, dtype=bool), np.array([0.1, 0.2, 0.3, 0.4]))
    assert m == {"accuracy": 1.0, "p_at_100r": 1.0, "r_at_100p": 1.0, "auc_pr": 1.0, "n_queries": 4}
    m = pr_metrics(np.zeros(3, dtype=bool), np.array([0.1, 0.2, 0.3]))
    assert m["r_at_100p"] == 0.0 and m["auc_pr"] == 0.0 and m["accuracy"] == 0.0


def test_empty_and_bad_input() -> None:
    with pytest.raises(ValueError):
        pr_metrics(np.array([], dtype=bool), np.array([]))
    with pytest.raises(ValueError):
        pr_curve(np.array([True]), np.array([0.1, 0.2]))
    with pytest.raises(ValueError):
        pr_metrics(np.array([True]), np.array([np.nan]))
    with pytest.raises(ValueError):
        pr_metrics(np.array([2]), np.array([0.5]))


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(st.booleans(), st.sampled_from([0.0, 0.1, 0.25, 0.5, 0.75, 1.0])),
        min_size=1,
        max_size=25,
    )
)
def test_matches_brute_force_threshold_sweep(rows: list[tuple[bool, float]]) -> None:
    correct = np.array([r[0] for r in rows])
    conf = np.array([r[1] for r in rows])
    n = len(rows)
    points = []
    for tau in sorted(set(conf.tolist()), reverse=True):
        acc = conf >= tau
        tp = int(np.sum(correct & acc))
        points.append((tp / acc.sum(), tp / n, tp == acc.sum()))
    precision, recall, _ = pr_curve(correct, conf)
    np.testing.assert_allclose(precision, [p for p, _, _ in points])
    np.testing.assert_allclose(recall, [r for _, r, _ in points])
    m = pr_metrics(correct, conf)
    expected_r = max([r for _, r, ok in points if ok], default=0.0)
    assert m["r_at_100p"] == pytest.approx(expected_r)
    auc, prev = 0.0, 0.0
    for p, r, _ in points:
        auc += (r - prev) * p
        prev = r
    assert m["auc_pr"] == pytest.approx(auc)
    assert m["p_at_100r"] == pytest.approx(m["accuracy"])
    assert all(0.0 <= m[key] <= 1.0 for key in ("accuracy", "p_at_100r", "r_at_100p", "auc_pr"))


def test_is_correct_tolerance_and_no_match() -> None:
    place_ids = np.array([100, 101, 102, 103])
    pred_index = np.array([0, 2, -1, 3])
    ids = predicted_place_ids(pred_index, place_ids)
    assert ids.mask.tolist() == [False, False, True, False]
    true = np.array([100, 101, 103, 103])
    assert is_correct(ids, true).tolist() == [True, False, False, True]
    # place_ids[-1] == 103 would have looked correct for query 2: it must not
    assert is_correct(ids, true, tolerance=1).tolist() == [True, True, False, True]
    # the same with a plain array and an explicit matched mask
    plain = np.array([100, 102, 103, 103])
    matched = pred_index >= 0
    assert is_correct(plain, true, 1, matched=matched).tolist() == [True, True, False, True]
    assert is_correct(plain, true).tolist() == [True, False, True, True]
    with pytest.raises(ValueError):
        is_correct(plain, true, -1)
    with pytest.raises(ValueError):
        is_correct(plain, true, matched=np.array([1, 1, 0, 1]))
    with pytest.raises(ValueError):
        predicted_place_ids(np.array([4]), place_ids)
