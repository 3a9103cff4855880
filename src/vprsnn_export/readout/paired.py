"""Paired statistics of two readouts of the same queries: flips, exact McNemar, paired bootstrap, a verdict.

The float network and a deployed (quantised) one see the *same* spike tensor, so every query is a pair (float
decision, deployed decision). Judging a metric difference with two independent samples would throw that pairing away;
here every interval is paired:

* **accuracy at k = 1**: only the discordant queries carry information. With b = #(float right, deployed wrong) and
  c = #(float wrong, deployed right), the exact McNemar test and an exact interval of the accuracy difference
  conditional on n = b + c (:func:`accuracy_interval`).
* **every metric, every k** (accuracy, P@100R, R@100P, AUC-PR): the paired bootstrap, both readouts resampled with the
  same query indices; for k > 1 the windows overlap, so the queries are resampled as moving blocks of length k
  (:func:`bootstrap_indices`). Vectorised over resamples.
* **the verdict** of a difference against a tolerance on its drop (:func:`verdict`): *holds*, *fails*, *undecided*
  (with :func:`queries_to_decide`), or *not judged* for a degenerate float metric.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from vprsnn_export.errors import InvalidValueError

from .assignment import finite_array
from .metrics import METRICS

#: The metrics the bootstrap measures on each resample (readout.metrics.pr_metrics' keys).
PAIRED_METRICS = METRICS
#: The verdicts of one check.
HOLDS, FAILS, UNDECIDED, NOT_JUDGED = "holds", "fails", "undecided", "not judged"
#: Most index entries (resamples x queries) one vectorised bootstrap chunk holds (about 32 MB per array).
CHUNK_ENTRIES = 1 << 22


def flips(float_correct: np.ndarray, deployed_correct: np.ndarray) -> tuple[int, int]:
    """The discordant pairs (b, c) of two per-query correctness vectors.

    .. math:: b = \\#\\{q : F_q \\wedge \\neg D_q\\}, \\qquad c = \\#\\{q : \\neg F_q \\wedge D_q\\}

    (the module docstring's b and c): the accuracy difference (deployed - float) is (c - b) / Q.
    """
    f, d = _pair(float_correct, deployed_correct)
    return int(np.sum(f & ~d)), int(np.sum(~f & d))


def binomial_cdf(x: int, n: int, p: float) -> float:
    """P(X <= x) for X ~ Binomial(n, p), summed exactly in log space.

    .. math:: P(X \\le x) = \\sum_{i=0}^{x} \\binom{n}{i} p^i (1-p)^{n-i}
    """
    if x < 0:
        return 0.0
    if x >= n or p <= 0.0:
        return 1.0
    if p >= 1.0:
        return 0.0
    i = np.arange(1, x + 1)
    log_binomial = np.concatenate(([0.0], np.cumsum(np.log(n - i + 1.0) - np.log(i))))  # log C(n, 0..x)
    log_terms = log_binomial + np.arange(x + 1) * math.log(p) + (n - np.arange(x + 1)) * math.log1p(-p)
    return float(min(1.0, np.exp(log_terms).sum()))


def mcnemar_exact(b: int, c: int) -> float:
    """Two-sided exact McNemar p-value of b and c discordant pairs.

    Under "no difference" each discordant pair is b or c with probability 1/2:

    .. math:: p = \\min\\Big(1,\\; 2 \\sum_{i=0}^{\\min(b,c)} \\binom{n}{i} 2^{-n}\\Big), \\qquad n = b + c

    (p = 1 when n = 0).
    """
    n = b + c  # b, c: the counts of :func:`flips`
    return 1.0 if n == 0 else min(1.0, 2.0 * binomial_cdf(min(b, c), n, 0.5))


def clopper_pearson(x: int, n: int, level: float) -> tuple[float, float]:
    """Exact (Clopper-Pearson) interval of a binomial proportion x / n at confidence ``level``.

    .. math:: p_{lo} = \\inf\\{p : P(X \\ge x; n, p) > \\alpha/2\\}, \\quad
              p_{hi} = \\sup\\{p : P(X \\le x; n, p) > \\alpha/2\\}, \\quad \\alpha = 1 - \\text{level}

    found by bisection on :func:`binomial_cdf` (p_lo = 0 when x = 0, p_hi = 1 when x = n).
    """
    _check_level(level)
    if not 0 <= x <= n or n < 1:
        raise InvalidValueError(f"clopper_pearson needs 0 <= x <= n and n >= 1, got x={x}, n={n}")
    alpha = 1.0 - level
    low = 0.0 if x == 0 else _bisect(lambda p: 1.0 - binomial_cdf(x - 1, n, p), alpha / 2, increasing=True)
    high = 1.0 if x == n else _bisect(lambda p: binomial_cdf(x, n, p), alpha / 2, increasing=False)
    return low, high


def _bisect(f: Callable[[float], float], target: float, *, increasing: bool) -> float:
    """The p in [0, 1] where the monotone f(p) crosses ``target`` (60 halvings: below 1e-18)."""
    lo, hi = 0.0, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        above = f(mid) >= target
        lo, hi = (lo, mid) if above == increasing else (mid, hi)
    return 0.5 * (lo + hi)


def accuracy_interval(b: int, c: int, n_queries: int, level: float) -> tuple[float, float]:
    """Exact paired interval of the accuracy difference (deployed - float) at confidence ``level``.

    Conditional on the n = b + c discordant queries, c ~ Binomial(n, pi) (the exact McNemar model), and the
    difference is (c - b) / Q = (n / Q)(2 pi - 1); the Clopper-Pearson interval [pi_lo, pi_hi] of c / n gives

    .. math:: \\Delta \\in \\Big[\\tfrac{n}{Q}(2\\pi_{lo} - 1),\\; \\tfrac{n}{Q}(2\\pi_{hi} - 1)\\Big]

    With no discordant query (n = 0) both readouts are right on the same queries: [0, 0].
    """
    if b < 0 or c < 0 or b + c > n_queries:
        raise InvalidValueError(f"need 0 <= b, c and b + c <= Q, got b={b}, c={c}, Q={n_queries}")
    n = b + c
    if n == 0:
        _check_level(level)
        return 0.0, 0.0
    low, high = clopper_pearson(c, n, level)
    return n / n_queries * (2 * low - 1), n / n_queries * (2 * high - 1)


def bootstrap_indices(n_queries: int, resamples: int, block: int, rng: np.random.Generator) -> np.ndarray:
    """Query indices of ``resamples`` moving-block bootstrap samples, (resamples, Q) int64.

    Each sample joins ceil(Q / L) blocks of L consecutive queries whose starts are uniform on {0, ..., Q - L}, cut to Q:

    .. math:: s_{b,j} \\sim U\\{0, \\dots, Q - L\\}, \\qquad
              \\text{idx}_b = (s_{b,1}, \\dots, s_{b,1} + L - 1, s_{b,2}, \\dots)_{1..Q}

    L = 1 is the ordinary bootstrap; L = k keeps the overlap of the k-frame windows inside a block.
    """
    if n_queries < 1 or resamples < 1 or not 1 <= block <= n_queries:
        raise InvalidValueError(
            f"bootstrap needs Q >= 1, resamples >= 1 and 1 <= block <= Q, got Q={n_queries}, "
            f"resamples={resamples}, block={block}"
        )
    n_blocks = -(-n_queries // block)
    starts = rng.integers(0, n_queries - block + 1, size=(resamples, n_blocks))
    return (starts[:, :, None] + np.arange(block)).reshape(resamples, -1)[:, :n_queries]


def resampled_metrics(correct: np.ndarray, confidence: np.ndarray, indices: np.ndarray) -> dict[str, np.ndarray]:
    """Accuracy, P@100R, R@100P and AUC-PR of every resample (rows of ``indices``), vectorised, no sort.

    Exactly :func:`readout.metrics.pr_metrics` per row. The queries are ranked once by confidence
    (descending); a resample is then the count m_{b,r} of each ranked query r in it. Over the groups g of
    equal confidence (ties are never split), TP and N are running sums:

    .. math:: TP_{b,g} = \\sum_{r \\le \\mathrm{end}(g)} m_{b,r} \\, \\mathrm{correct}_r, \\qquad
              N_{b,g} = \\sum_{r \\le \\mathrm{end}(g)} m_{b,r}

    .. math:: \\mathrm{R@100P}_b = \\max_g \\{TP_{b,g} / Q : TP_{b,g} = N_{b,g}\\}, \\qquad
              \\mathrm{AUC}_b = \\frac{1}{Q} \\sum_g (TP_{b,g} - TP_{b,g-1}) \\frac{TP_{b,g}}{N_{b,g}}

    (a group absent from a resample adds nothing); accuracy = P@100R = TP_{b,last} / Q.
    """
    c, conf = _pair(correct, confidence, second_real=True)
    order = np.argsort(-conf, kind="stable")
    rank = np.argsort(order)  # the inverse permutation: query -> its rank
    idx = np.asarray(indices)
    resamples, n = idx.shape
    flat = (np.arange(resamples)[:, None] * c.size + rank[idx]).ravel()
    counts = np.bincount(flat, minlength=resamples * c.size).reshape(resamples, c.size)
    conf_sorted = conf[order]
    ends = np.flatnonzero(np.append(conf_sorted[1:] != conf_sorted[:-1], True))
    tp = np.cumsum(counts * c[order], axis=1)[:, ends]
    accepted = np.cumsum(counts, axis=1)[:, ends]
    gained = np.diff(tp, axis=1, prepend=0)
    accuracy = tp[:, -1] / n
    return {
        "accuracy": accuracy,
        "p_at_100r": accuracy,
        "r_at_100p": np.where(tp == accepted, tp, 0).max(axis=1) / n,
        "auc_pr": (gained * tp / np.maximum(accepted, 1)).sum(axis=1) / n,
    }


def paired_bootstrap(
    float_correct: np.ndarray,
    float_confidence: np.ndarray,
    deployed_correct: np.ndarray,
    deployed_confidence: np.ndarray,
    *,
    block: int,
    resamples: int,
    level: float,
    seed: int,
) -> dict[str, tuple[float, float]]:
    """Percentile interval of each metric's difference (deployed - float) over paired resamples.

    Both readouts are scored on the *same* resampled queries (:func:`bootstrap_indices`, block length
    ``block``), so the pairing cancels what the queries share:

    .. math:: \\Delta^*_b = M(D_{\\text{idx}_b}) - M(F_{\\text{idx}_b}), \\qquad
              [\\Delta^*_{(\\alpha/2)}, \\Delta^*_{(1 - \\alpha/2)}], \\quad \\alpha = 1 - \\text{level}

    Seeded (``seed``), vectorised over resamples in chunks of at most :data:`CHUNK_ENTRIES` indices.
    """
    _check_level(level)
    f_correct, f_confidence = _pair(float_correct, float_confidence, second_real=True)
    d_correct, d_confidence = _pair(deployed_correct, deployed_confidence, second_real=True)
    n = f_correct.shape[0]
    if d_correct.shape != (n,):
        raise InvalidValueError(f"float ({n}) and deployed ({d_correct.shape[0]}) readouts must score the same queries")
    rng = np.random.default_rng(seed)
    per_chunk = max(1, CHUNK_ENTRIES // max(n, 1))
    deltas: dict[str, list[np.ndarray]] = {m: [] for m in PAIRED_METRICS}
    for start in range(0, resamples, per_chunk):
        idx = bootstrap_indices(n, min(per_chunk, resamples - start), block, rng)
        f = resampled_metrics(f_correct, f_confidence, idx)
        d = resampled_metrics(d_correct, d_confidence, idx)
        for m in PAIRED_METRICS:
            deltas[m].append(d[m] - f[m])
    alpha = 1.0 - level
    quantiles = {m: np.quantile(np.concatenate(deltas[m]), [alpha / 2, 1 - alpha / 2]) for m in PAIRED_METRICS}
    return {m: (float(low), float(high)) for m, (low, high) in quantiles.items()}


def verdict(low: float, high: float, limit: float, eps: float = 1e-12) -> str:
    """Three-way verdict of the interval [low, high] of a difference (deployed - float) against a drop limit.

    .. math:: \\text{holds}: \\; low \\ge -\\ell, \\qquad \\text{fails}: \\; high < -\\ell, \\qquad
              \\text{undecided otherwise (the interval straddles } -\\ell)

    A deployed network that does better than float never fails (only the drop is bounded);
    ``eps`` absorbs float rounding.
    """
    if low > high or limit < 0:
        raise InvalidValueError(f"verdict needs low <= high and limit >= 0, got [{low}, {high}], limit {limit}")
    if low >= -limit - eps:
        return HOLDS
    if high < -limit - eps:
        return FAILS
    return UNDECIDED


def degenerate(metric: str, float_value: float) -> str | None:
    """Why a metric difference is not judged, or None: a float value of 0 leaves nothing to lose, and an interval around
    0 - 0 says nothing about the deployed network (float R@100P = 0: no decision is accepted at 100 % precision)."""
    if float_value > 0:
        return None
    if metric == "r_at_100p":
        return "not judged: float R@100P = 0 (no decision accepted at 100 % precision)"
    return f"not judged: the float network's {metric} is 0"


def queries_to_decide(estimate: float, low: float, high: float, limit: float, n_queries: int) -> int | None:
    """Roughly how many queries would decide an undecided check: the half-width facing the limit shrinks as
    1 / sqrt(Q), the difference staying the same:

    .. math:: Q' = \\Big\\lceil Q \\Big(\\frac{h}{|\\hat\\Delta + \\ell|}\\Big)^2 \\Big\\rceil, \\qquad
              h = \\begin{cases} \\hat\\Delta - low & \\hat\\Delta > -\\ell \\ high - \\hat\\Delta & \\text{else} \\end{cases}

    None when the estimate sits on the limit (no number of queries decides it).
    """
    gap = estimate + limit
    if abs(gap) < 1e-12:
        return None
    half = estimate - low if gap > 0 else high - estimate
    return max(n_queries, math.ceil(n_queries * (half / abs(gap)) ** 2))


def _check_level(level: float) -> None:
    if not 0.0 < level < 1.0:
        raise InvalidValueError(f"confidence level must lie in (0, 1), got {level}")


def _pair(a: np.ndarray, b: np.ndarray, *, second_real: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Two 1-D arrays of equal length: a boolean (correctness) and a boolean or finite real one."""
    x, y = np.asarray(a), np.asarray(b)
    if x.ndim != 1 or y.shape != x.shape:
        raise InvalidValueError(f"paired arrays must be 1-D of equal length, got {x.shape} and {y.shape}")
    if x.dtype != np.bool_ or not (second_real or y.dtype == np.bool_):
        raise InvalidValueError("correctness must be a boolean array")
    return x, finite_array("confidence", y) if second_real else y
