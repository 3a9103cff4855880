"""report.json -> report.md and a self-contained report.html; several reports -> one, as mean ± std.

Built from the JSON alone (nothing is re-run): a list of blocks (:mod:`.blocks`, figures by :mod:`.plots`) rendered
as Markdown with PNGs in ``plots/`` and as HTML with inline PNGs (:mod:`.render`). Reading and pooling reports:
:mod:`.load`; the cells' formats: :mod:`.labels`.
"""

from .load import combine_reports, load_report, report_path
from .render import write_report

__all__ = ["combine_reports", "load_report", "report_path", "write_report"]
