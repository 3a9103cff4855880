"""report.json -> report.md and a self-contained report.html; several reports -> one, as mean ± std.

The report is built from the JSON alone (nothing is re-run), so ``vprsnn-export report``
can rebuild it anywhere. The document is a list of blocks (headings, paragraphs,
tables, figures; :mod:`.blocks`, their figures drawn by :mod:`.plots`) rendered twice
(:mod:`.render`): Markdown, whose figures are PNG files in ``plots/`` beside it, and HTML,
whose figures are base64 PNGs inline (matplotlib Agg, no external asset of any kind).
Reading a report.json and pooling several is :mod:`.load`; the cells' formats are :mod:`.labels`.
"""

from .load import combine_reports, load_report, report_path
from .render import write_report

__all__ = ["combine_reports", "load_report", "report_path", "write_report"]
