"""report.json -> report.md and a self-contained report.html (nothing re-run); several reports -> one, mean ± std."""

from .load import combine_reports, load_report, report_path
from .render import write_report

__all__ = ["combine_reports", "load_report", "report_path", "write_report"]
