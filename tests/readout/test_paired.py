"""Paired statistics of float vs deployed readouts: flips, exact McNemar, paired (block) bootstrap, verdict."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.readout.metrics import pr_metrics
from vprsnn_export.readout.paired import (
    FAILS,
    HOLDS,
    PAIRED_METRICS,
    UNDECIDED,
    accuracy_interval,
    binomial_cdf,
    bootstrap_indices,
    clopper_pearson,
    degenerate,
    flips,
    mcnemar_exact,
    paired_bootstrap,
    queries_to_decide,
    resampled_metrics,
    verdict,
)

LEVEL = 0.95


def _pairs(q: int, b: int, c: int) -> tuple[np.ndarray, np.ndarray]:
    """Q queries, float right on the first half; b of those deployed wrong, c of the others deployed right."""
    f = np.arange(q) < q // 2
    d = f.copy()
    d[:b] = False
    d[q // 2 : q // 2 + c] = True
    return f, d


def test_flips_count_the_discordant_pairs():
    f, d = _pairs(100, 3, 1)
    assert flips(f, d) == (3, 1)
    assert (d.mean() - f.mean()) == pytest.approx((1 - 3) / 100)


def test_mcnemar_matches_the_hand_computed_binomial_value():
    # b = 1, c = 7: n = 8, p = 2 * (C(8,0) + C(8,1)) / 2**8 = 18 / 256
    assert mcnemar_exact(1, 7) == pytest.approx(18 / 256, abs=1e-15)
    assert mcnemar_exact(7, 1) == mcnemar_exact(1, 7)
    # b = 0, c = 5: 2 * 1 / 32
    assert mcnemar_exact(0, 5) == pytest.approx(1 / 16, abs=1e-15)
    assert mcnemar_exact(4, 4) == 1.0 and mcnemar_exact(0, 0) == 1.0
    assert binomial_cdf(2, 10, 0.3) == pytest.approx(sum(math.comb(10, i) * 0.3**i * 0.7 ** (10 - i) for i in range(3)))


def test_clopper_pearson_bounds_reach_alpha_over_two():
    low, high = clopper_pearson(3, 10, LEVEL)
    assert (low, high) == pytest.approx((0.066739512, 0.652452850), abs=1e-8)  # published table value
    assert 1 - binomial_cdf(2, 10, low) == pytest.approx(0.025, abs=1e-9)
    assert binomial_cdf(3, 10, high) == pytest.approx(0.025, abs=1e-9)
    assert clopper_pearson(0, 5, LEVEL)[0] == 0.0 and clopper_pearson(5, 5, LEVEL)[1] == 1.0


def test_a_case_that_must_hold():
    f, d = _pairs(100, 1, 0)  # one query of 100 lost, limit 2 points
    low, high = accuracy_interval(*flips(f, d), 100, LEVEL)
    assert low == pytest.approx(-0.01) and high > 0
    assert verdict(low, high, 0.02) == HOLDS
    assert accuracy_interval(0, 0, 100, LEVEL) == (0.0, 0.0)


def test_a_case_that_must_fail():
    f, d = _pairs(100, 30, 0)  # 30 queries lost, none won: the whole interval is below -2 points
    low, high = accuracy_interval(*flips(f, d), 100, LEVEL)
    assert high < -0.2 and verdict(low, high, 0.02) == FAILS
    assert mcnemar_exact(30, 0) < 1e-8


def test_a_case_that_must_stay_undecided_and_says_how_many_queries_decide_it():
    # three queries lost of 100: the point estimate (-3 points) misses a 2-point limit, but three flips
    # are within the paired noise: the interval straddles the limit
    f, d = _pairs(100, 3, 0)
    b, c = flips(f, d)
    low, high = accuracy_interval(b, c, 100, LEVEL)
    assert low < -0.02 < high and verdict(low, high, 0.02) == UNDECIDED
    estimate = (c - b) / 100
    needed = queries_to_decide(estimate, low, high, 0.02, 100)
    # (high - estimate) / |estimate + limit| = half-width over the gap, squared, times Q
    assert needed == math.ceil(100 * ((high - estimate) / 0.01) ** 2) and needed > 100
    assert queries_to_decide(-0.02, -0.05, 0.01, 0.02, 100) is None  # on the limit: nothing decides it


def test_a_degenerate_metric_is_not_judged():
    assert degenerate("r_at_100p", 0.0).startswith("not judged: float R@100P = 0")
    assert degenerate("auc_pr", 0.0).startswith("not judged")
    assert degenerate("r_at_100p", 0.01) is None


def test_resampled_metrics_equal_pr_metrics_on_every_resample():
    rng = np.random.default_rng(3)
    correct = rng.random(41) < 0.4
    confidence = np.round(rng.random(41), 1)  # many ties: never split
    idx = bootstrap_indices(41, 30, 3, rng)
    got = resampled_metrics(correct, confidence, idx)
    for b in range(30):
        want = pr_metrics(correct[idx[b]], confidence[idx[b]])
        assert all(got[m][b] == pytest.approx(want[m], abs=1e-12) for m in PAIRED_METRICS)


def test_block_indices_are_runs_of_k_consecutive_queries():
    idx = bootstrap_indices(10, 4, 3, np.random.default_rng(0))
    assert idx.shape == (4, 10) and idx.min() >= 0 and idx.max() <= 9
    blocks = idx[:, :9].reshape(4, 3, 3)
    assert np.all(np.diff(blocks, axis=2) == 1)
    with pytest.raises(InvalidValueError, match="block"):
        bootstrap_indices(5, 4, 6, np.random.default_rng(0))


def test_paired_bootstrap_identical_readouts_and_a_confident_wrong_answer():
    rng = np.random.default_rng(1)
    q = 100
    correct = np.arange(q) < 60
    confidence = np.where(correct, 0.5 + rng.random(q) / 2, rng.random(q) / 2)  # float: R@100P = 0.6
    same = paired_bootstrap(correct, confidence, correct, confidence, block=1, resamples=500, level=LEVEL, seed=0)
    assert all(same[m] == (0.0, 0.0) for m in PAIRED_METRICS)
    # deployed: the same answers, but its ten most confident decisions are wrong ones
    deployed_conf = confidence.copy()
    deployed_conf[90:] = 2.0
    out = paired_bootstrap(correct, confidence, correct, deployed_conf, block=1, resamples=500, level=LEVEL, seed=0)
    assert out["accuracy"] == (0.0, 0.0)
    low, high = out["r_at_100p"]
    assert high < -0.3 and verdict(low, high, 0.01) == FAILS
    again = paired_bootstrap(correct, confidence, correct, deployed_conf, block=3, resamples=500, level=LEVEL, seed=0)
    assert again == paired_bootstrap(
        correct, confidence, correct, deployed_conf, block=3, resamples=500, level=LEVEL, seed=0
    )  # seeded: deterministic


@pytest.mark.parametrize(
    "call",
    [
        lambda: clopper_pearson(3, 10, 1.0),
        lambda: accuracy_interval(60, 50, 100, LEVEL),
        lambda: flips(np.ones(3, bool), np.ones(4, bool)),
        lambda: verdict(0.1, -0.1, 0.01),
        lambda: paired_bootstrap(
            np.ones(3, bool), np.ones(3), np.ones(3, bool), np.full(3, np.nan), block=1, resamples=5, level=0.9, seed=0
        ),
    ],
)
def test_bad_input_is_one_clear_error(call):
    with pytest.raises(InvalidValueError):
        call()
