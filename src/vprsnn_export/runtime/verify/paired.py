"""The paired table of `verify`: every readout (strategy at k) of float and deployed judged as pairs of queries.

The statistics are :mod:`vprsnn_export.readout.paired`'s; this module picks what each readout is judged
against (the tolerances, as :func:`.checks.tolerance_checks` applies them) and builds the typed
:class:`~vprsnn_export.runtime.results.PairedCheck` rows.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from vprsnn_export.config import VerifyConfig
from vprsnn_export.readout import paired

from ..results import MetricRow, PairedCheck, ToleranceCheck, find_row

#: The metrics of the paired table (P@100R equals accuracy: it is added only when its tolerance is on).
TABLE_METRICS = ("accuracy", "r_at_100p", "auc_pr")
#: The tolerances the paired verdicts judge (the others, winner agreement, top-1 agreement, saturations, are
#: bounds on one measured number and stay point checks).
PAIRED_TOLERANCES = ("accuracy", "p_at_100r", "r_at_100p", "auc_pr")
#: One readout's per-query (correct, confidence), per (strategy, k): :meth:`~vprsnn_export.readout.scored.Scored.decisions`.
Decisions = dict[tuple[str, int], tuple[np.ndarray, np.ndarray]]


def paired_checks(
    float_decisions: Decisions,
    decisions: Decisions,
    rows: Sequence[MetricRow],
    limits: Mapping[tuple[str, str, int], float],
    settings: VerifyConfig,
) -> tuple[PairedCheck, ...]:
    """The paired table of one bit width: per readout and metric the flips, the difference, its interval
    and the verdict against ``limits`` (:func:`.checks.judged_limits`); ``rows`` are the deployed rows with their
    float values (:func:`.checks.metric_deltas`)."""
    out = []
    for (strategy, k), floats in float_decisions.items():
        deployed = decisions[(strategy, k)]  # (correct, confidence) per query, like floats
        row = find_row(rows, strategy, k)
        if row is None or row.delta is None or row.float_values is None:
            continue
        boot = paired.paired_bootstrap(
            *floats, *deployed, block=k, resamples=settings.resamples, level=settings.confidence, seed=settings.seed
        )
        b, c = paired.flips(floats[0], deployed[0])
        n = row.n_queries
        for metric in [*TABLE_METRICS, *(["p_at_100r"] if ("p_at_100r", strategy, k) in limits else [])]:
            exact = metric == "accuracy" and k == 1
            low, high = paired.accuracy_interval(b, c, n, settings.confidence) if exact else boot[metric]
            estimate = row.delta.get(metric)
            limit = limits.get((metric, strategy, k))
            note = None if limit is None else paired.degenerate(metric, row.float_values.get(metric))
            verdict = None if limit is None else paired.NOT_JUDGED if note else paired.verdict(low, high, limit)
            block = "paired bootstrap" if k == 1 else f"paired block bootstrap (blocks of {k})"
            out.append(
                PairedCheck(
                    strategy=strategy,
                    k=k,
                    metric=metric,
                    n_queries=n,
                    float_right_deployed_wrong=b,
                    float_wrong_deployed_right=c,
                    float_value=row.float_values.get(metric),
                    difference=estimate,
                    low=low,
                    high=high,
                    method="exact McNemar" if exact else block,
                    p_value=paired.mcnemar_exact(b, c) if exact else None,
                    limit=limit,
                    verdict=verdict,
                    queries_to_decide=paired.queries_to_decide(estimate, low, high, limit, n)
                    if verdict == paired.UNDECIDED and limit is not None
                    else None,
                    note=note,
                )
            )
    return tuple(out)


def bits_passed(cross_passed: bool, checks: Sequence[ToleranceCheck], table: Sequence[PairedCheck]) -> bool:
    """A bit width passes when every cross-implementation check is exact, every point check that is not a
    metric's (winner agreement, top-1 agreement, saturations) holds, and no paired interval fails: a metric
    tolerance is judged by its paired verdict, never by the point difference alone."""
    points = all(c.passed for c in checks if c.check not in PAIRED_TOLERANCES)
    return bool(cross_passed and points and not any(c.verdict == paired.FAILS for c in table))
