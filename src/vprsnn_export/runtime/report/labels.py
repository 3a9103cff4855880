"""The report's cells: metric and readout titles, mean ± std and signed percentages, verdicts."""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Any

from vprsnn_export.readout.strategies import STRATEGIES
from vprsnn_export.stats import MeanStd

from ..results import BitsResult, ConformanceResult, PairedCheck, VerifiedRun, VerifyReport

METRIC_TITLES = {"accuracy": "Accuracy", "p_at_100r": "P@100R", "r_at_100p": "R@100P", "auc_pr": "AUC-PR"}


def signed_pct(value: float | None, digits: int = 1) -> str:
    return "-" if value is None else f"{round(100 * value, digits) + 0.0:+.{digits}f}"


def ms(summary: MeanStd | None, *, percent: bool = True, signed: bool = False, digits: int = 1) -> str:
    """A mean ± std cell (just the mean for a single run)."""
    if summary is None or summary.mean is None:
        return "-"
    scale = 100.0 if percent else 1.0
    value = round(scale * summary.mean, digits) + 0.0  # no "-0.0"
    mean = f"{value:{'+' if signed else ''}.{digits}f}"
    return mean if summary.n <= 1 else f"{mean} ± {scale * (summary.std or 0.0):.{digits}f}"


def data_label(data: Mapping[str, Any]) -> str:
    """ "DATA (selection)" of a ``{data or source, subset, places}`` mapping ("-" when it names no data)."""
    source = data.get("data") or data.get("source")
    if not source:
        return "-"
    selection = data.get("subset") or (f"places {data['places']}" if data.get("places") else "all places")
    return f"{source} ({selection})"


def strategy_title(strategy: str) -> str:
    """A strategy's title in the report (its registry entry's; a name not registered stays as it is)."""
    return STRATEGIES.get(strategy).title if strategy in STRATEGIES else strategy


def row_label(strategy: str, k: int) -> str:
    return f"{strategy_title(strategy)} k={k}"


def verdict(passed: bool) -> str:
    return "PASS" if passed else "FAIL"


def network_label(run: VerifiedRun, index: int) -> str:
    return run.label or str(index + 1)


def points(check: str, value: float) -> str:
    """A tolerance value in the unit the terminal also uses: percentage points, or a count (saturations)."""
    return str(int(value)) if check == "saturations" else f"{100 * value:.1f} pts"


#: The paired table's columns (key, title), the same in the terminal, report.md and report.html.
PAIRED_COLUMNS = (
    ("readout", "readout"),
    ("metric", "metric"),
    ("float", "float %"),
    ("difference", "Δ (pts)"),
    ("interval", "interval (pts)"),
    ("flips", "flips -/+"),
    ("limit", "drop limit (pts)"),
    ("verdict", "verdict"),
)


def paired_cells(check: PairedCheck) -> dict[str, str]:
    """One paired check as text cells: Δ and its interval in points, the flips, the limit and the verdict."""
    verdict_text = check.verdict or "reported"
    if check.verdict == "undecided":
        verdict_text += (
            f" (~{check.queries_to_decide} queries decide)" if check.queries_to_decide else " (on the limit)"
        )
    elif check.note and check.verdict == "not judged":
        verdict_text = check.note
    return {
        "readout": row_label(check.strategy, check.k),
        "metric": METRIC_TITLES.get(check.metric, check.metric),
        "float": f"{100 * check.float_value:.1f}",
        "difference": signed_pct(check.difference),
        "interval": f"[{signed_pct(check.low)}, {signed_pct(check.high)}]",
        "flips": f"{check.float_right_deployed_wrong}/{check.float_wrong_deployed_right}",
        "limit": "-" if check.limit is None else f"{100 * check.limit:.1f}",
        "verdict": verdict_text,
    }


def shown_paired(checks: Sequence[PairedCheck]) -> list[PairedCheck]:
    """The paired checks a table shows: every judged one, and the accuracy of every readout (its flips)."""
    return [c for c in checks if c.limit is not None or c.metric == "accuracy"]


def verdict_counts(checks: Sequence[PairedCheck]) -> str:
    """ "1 fail, 2 hold" over the judged checks, worst verdict first."""
    counts = Counter(check.verdict for check in checks)
    names = {"fails": "fail", "undecided": "undecided", "not judged": "not judged", "holds": "hold"}
    return ", ".join(f"{counts[v]} {name}" for v, name in names.items() if counts[v])


def exact_counts(results: Sequence[ConformanceResult]) -> str:
    """ "37/37": the exact rows (any difference fails) that are identical, summed over ``results``."""
    return f"{sum(r.n_identical for r in results)}/{sum(r.n_exact for r in results)}"


def tolerance_counts(results: Sequence[ConformanceResult]) -> str:
    """ "2/2": the tolerance rows (float consumers) within their stated agreement; "-" when there are none."""
    total = sum(r.n_tolerance for r in results)
    return f"{sum(r.n_within_tolerance for r in results)}/{total}" if total else "-"


def cross_counts(results: Sequence[ConformanceResult]) -> str:
    """ "37/37 exact, 2/2 within tolerance" (:func:`exact_counts`, :func:`tolerance_counts`) on one line."""
    tolerance = tolerance_counts(results)
    return f"{exact_counts(results)} exact" + (f", {tolerance} within tolerance" if tolerance != "-" else "")


#: The verdict table's columns (key, title), the same in the terminal, report.md and report.html: exact rows
#: and tolerance rows (float consumers) in columns of their own.
VERDICT_COLUMNS = (
    ("network", "network"),
    ("bits", "bits"),
    ("verdict", "verdict"),
    ("paired", "paired checks"),
    ("exact", "exact rows identical"),
    ("tolerance", "tolerance rows within"),
    ("accuracy", "worst accuracy Δ k=1 (pts)"),
    ("r_at_100p", "R@100P Δ W+Prob (pts)"),
    ("winner", "same winner %"),
    ("saturations", "saturations"),
)


def results(report: VerifyReport) -> list[tuple[str, VerifiedRun, BitsResult]]:
    """(network label, network, its result at one bit width) of every network and bit width, in order."""
    return [(network_label(run, i), run, result) for i, run in enumerate(report.runs) for result in run.bits]


def verdict_cells(label: str, run: VerifiedRun, result: BitsResult) -> dict[str, str]:
    """One network's bit width as the verdict table's cells (:data:`VERDICT_COLUMNS`)."""
    top = max(run.ks)

    def delta(strategy: str, k: int, metric: str) -> float:
        row = result.row(strategy, k)
        return 0.0 if row.delta is None else row.delta.get(metric)

    cross = [result.cross_implementation]
    return {
        "network": label,
        "bits": str(result.bits),
        "verdict": result.verdict + (" (degenerate float)" if run.degenerate else ""),
        "paired": verdict_counts(result.paired) or "-",
        "exact": exact_counts(cross),
        "tolerance": tolerance_counts(cross),
        "accuracy": signed_pct(min(delta(s, 1, "accuracy") for s in STRATEGIES)),
        "r_at_100p": f"{signed_pct(delta('wprob', top, 'r_at_100p'))} (k={top})",
        "winner": f"{100 * result.spike_level.winner_agreement:.1f}",
        "saturations": str(result.spike_level.saturations),
    }


def tolerance_differences(result: ConformanceResult) -> str:
    """Each tolerance row's measured difference: "snntorch: 1.9 % of 100 decisions differ (limit 5.0 %)"."""
    cells = [
        f"{row.a}: not gated (refuses the file)"
        if row.difference is None
        else f"{row.a}: {100 * row.difference:.1f} % of {row.n_elements} decisions differ "
        f"(limit {100 * (1 - (row.tolerance or 0.0)):.1f} %)"
        for row in result.tolerance_rows
    ]
    return "; ".join(cells) or "-"
