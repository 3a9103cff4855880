"""Reading a report.json, and several reports pooled into one (mean ± std)."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.io.fileio import parse_json

from ..results import ReportError, VerifyReport
from ..verify.summary import build_report, summarise_runs

REPORT_JSON = "report.json"


def report_path(path: str | Path) -> Path:
    """A run folder (holding report.json) or the report.json itself."""
    path = Path(path)
    return path / REPORT_JSON if path.is_dir() else path


def load_report(path: str | Path) -> VerifyReport:
    """The report of a report.json (or of the folder holding one); ReportError when it is not one."""
    file = report_path(path)
    if not file.is_file():
        raise ReportError(f"no {REPORT_JSON} here (give a folder written by verify, or its {REPORT_JSON})", file)
    try:
        data = parse_json(file.read_bytes(), REPORT_JSON)
    except (UnicodeDecodeError, json.JSONDecodeError, InvalidValueError) as exc:
        raise ReportError(f"not valid JSON ({exc})", file) from None
    return VerifyReport.from_dict(data, str(file))


#: Settings that make two verification runs measure different things: pooling them into one
#: mean ± std needs the user's explicit consent (``allow_mixed``).
POOLING_KEYS = (
    *("query", "data", "subset", "places", "bits", "readout"),
    *("per_neuron", "scale_method", "fold_thresholds", "calibration", "non_leaky"),
)
#: What a setting absent from an older report stands for (verify could not fold thresholds or drop the leak).
OLDER_DEFAULTS = {"fold_thresholds": False, "non_leaky": False}


def combine_reports(
    reports: Sequence[VerifyReport], sources: Sequence[str] | None = None, *, allow_mixed: bool = False
) -> VerifyReport:
    """One report of every run of ``reports`` (one or more; a :data:`POOLING_KEYS` difference needs ``allow_mixed``)."""
    if len(reports) == 1:
        return dataclasses.replace(reports[0], summary=summarise_runs(reports[0].runs))

    def setting(report: VerifyReport, key: str) -> str:
        """A setting as JSON text (a tuple equals the list a JSON file gives back); absent, its older default."""
        return json.dumps(report.settings.get(key, OLDER_DEFAULTS.get(key)), sort_keys=True, default=str)

    first, runs = reports[0], [run for report in reports for run in report.runs]
    keys = {key for report in reports for key in report.settings}
    differ = sorted({key for key in keys for report in reports[1:] if setting(report, key) != setting(first, key)})
    incompatible = [key for key in differ if key in POOLING_KEYS]
    if incompatible and not allow_mixed:
        raise ReportError(
            f"the reports differ in {', '.join(incompatible)}: pooling them into one mean ± std would mix different "
            "measurements (--allow-mixed to pool them anyway)"
        )
    return dataclasses.replace(
        build_report(runs, dict(first.settings), command=None),
        seconds=sum(float(report.seconds or 0) for report in reports),
        combined_from=tuple(sources or ()),
        commands=tuple(report.command for report in reports),
        settings_differ=tuple(differ),
    )
