"""verify's paired table: which readouts are judged, the verdict of constructed float/deployed pairs, the exit."""

from __future__ import annotations

import numpy as np
import pytest

from vprsnn_export.config import VerifyConfig
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.readout.metrics import pr_metrics
from vprsnn_export.readout.scoring import metric_row
from vprsnn_export.runtime.results import ToleranceCheck
from vprsnn_export.runtime.verify.checks import DEFAULT_TOLERANCES, judged_limits, parse_tolerances
from vprsnn_export.runtime.verify.paired import bits_passed, paired_checks

SETTINGS = VerifyConfig(resamples=400)
Q = 100


def _decisions(correct: np.ndarray, confidence: np.ndarray) -> dict:
    return {(s, 1): (correct, confidence) for s in ("standard", "weighted", "wprob")}


def _table(f_correct, f_conf, d_correct, d_conf, tolerances=None):
    rows = [
        metric_row(s, 1, pr_metrics(d_correct, d_conf)).with_float(metric_row(s, 1, pr_metrics(f_correct, f_conf)))
        for s in ("standard", "weighted", "wprob")
    ]
    limits = judged_limits(parse_tolerances(tolerances), (1,), Q)
    table = paired_checks(_decisions(f_correct, f_conf), _decisions(d_correct, d_conf), rows, limits, SETTINGS)
    return {(c.strategy, c.metric): c for c in table}


def _float():
    rng = np.random.default_rng(0)
    correct = np.arange(Q) < 50
    return correct, np.where(correct, 0.5 + rng.random(Q) / 2, rng.random(Q) / 2)  # R@100P = 0.5


def test_judged_limits_follow_the_tolerances():
    limits = judged_limits(DEFAULT_TOLERANCES, (1, 3, 5), 100)
    assert limits[("accuracy", "standard", 1)] == 0.02
    assert {k for (m, s, k) in limits if m == "r_at_100p"} == {1, 3, 5}
    assert not any(m in ("auc_pr", "p_at_100r") for m, _, _ in limits)  # off by default
    scattered = judged_limits(DEFAULT_TOLERANCES, (1, 3, 5), 100, sequences=False)
    assert {k for (m, s, k) in scattered if m == "r_at_100p"} == {1}
    no_one = judged_limits(parse_tolerances("auc_pr=0"), (3, 5), 100, sequences=False)  # verify --k 3,5, scattered
    assert {k for (m, s, k) in no_one if m == "r_at_100p"} == set() and ("auc_pr", "wprob", 1) in no_one
    slack = judged_limits(parse_tolerances("auc_pr=0"), (1, 3), 40)
    assert slack[("auc_pr", "wprob", 3)] == pytest.approx(1 / 40)  # query_slack: one query's worth


def test_three_queries_lost_of_100_is_undecided_and_does_not_fail_the_width():
    f_correct, f_conf = _float()
    d_correct = f_correct.copy()
    d_correct[:3] = False  # three of the float network's right answers lost: -3 points, limit 2
    table = _table(f_correct, f_conf, d_correct, f_conf)
    acc = table[("standard", "accuracy")]
    assert (acc.float_right_deployed_wrong, acc.float_wrong_deployed_right) == (3, 0)
    assert (
        acc.difference == pytest.approx(-0.03) and acc.method == "exact McNemar" and acc.p_value == pytest.approx(0.25)
    )
    assert acc.low < -0.02 < acc.high and acc.verdict == "undecided" and acc.queries_to_decide > Q
    assert table[("standard", "auc_pr")].verdict is None  # no tolerance: reported only
    assert bits_passed(True, [], tuple(table.values()))


def test_thirty_queries_lost_fails_the_width():
    f_correct, f_conf = _float()
    d_correct = f_correct.copy()
    d_correct[:30] = False
    table = _table(f_correct, f_conf, d_correct, f_conf)
    assert table[("wprob", "accuracy")].verdict == "fails" and table[("wprob", "accuracy")].high < -0.02
    assert not bits_passed(True, [], tuple(table.values()))


def test_identical_readouts_hold_and_float_r_at_100p_zero_is_not_judged():
    f_correct, f_conf = _float()
    table = _table(f_correct, f_conf, f_correct, f_conf)
    assert {c.verdict for c in table.values() if c.limit is not None} == {"holds"}
    assert all(c.low == c.high == 0.0 for c in table.values())
    wrong_first = f_conf.copy()
    wrong_first[-1] = 2.0  # the float network's most confident answer is wrong: R@100P = 0
    degenerate = _table(f_correct, wrong_first, f_correct, f_conf)
    r = degenerate[("wprob", "r_at_100p")]
    assert r.float_value == 0.0 and r.verdict == "not judged" and "float R@100P = 0" in r.note
    assert bits_passed(True, [], tuple(degenerate.values()))


def test_point_checks_and_cross_implementation_still_fail_a_width():
    point = ToleranceCheck("winner_agreement", "steps with the float winner", 0.5, 0.9, 0.9, False)
    metric = ToleranceCheck("accuracy", "accuracy drop, standard k=1", 0.03, 0.02, 0.02, False)
    assert not bits_passed(True, [point], ())
    assert bits_passed(True, [metric], ())  # a metric tolerance is judged on its paired interval
    assert not bits_passed(False, [], ())


def test_verify_settings_are_checked():
    with pytest.raises(InvalidValueError, match="verify.confidence"):
        VerifyConfig(confidence=1.0)
    with pytest.raises(InvalidValueError, match="verify.resamples"):
        VerifyConfig(resamples=0)
    assert VerifyConfig.from_dict({"seed": 3}) == VerifyConfig(seed=3)
