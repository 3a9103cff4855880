"""The blocks rendered as Markdown (figures in plots/) and as one self-contained HTML file; write_report."""

from __future__ import annotations

import base64
import html
import json
import re
from collections.abc import Sequence
from itertools import zip_longest
from pathlib import Path

from vprsnn_export.io.fileio import atomic_write_bytes, atomic_write_text

from ..results import VerifyReport
from .blocks import Block, blocks_of, one_line
from .load import REPORT_JSON

REPORT_MD = "report.md"
REPORT_HTML = "report.html"
PLOTS_DIR = "plots"
HEADINGS = ("h1", "h2", "h3")


#: Markdown's inline control characters, escaped in table cells (which hold stored strings: labels, paths).
MARKDOWN_SPECIAL = re.compile(r"([\\`*_\[\]<>|~#!])")


def markdown_cell(value: object) -> str:
    """A table cell's text, on one line and with Markdown's control characters escaped (``|`` -> ``\\|``)."""
    return MARKDOWN_SPECIAL.sub(r"\\\1", one_line(value))


def fence(text: str) -> str:
    """A code fence longer than any run of backticks in ``text`` (so ``text`` cannot close it)."""
    longest = max((len(run) for run in re.findall(r"`+", text)), default=0)
    return "`" * max(3, longest + 1)


def render_markdown(blocks: Sequence[Block], plots_dir: str = PLOTS_DIR) -> str:
    """The blocks as Markdown; every stored string stays on its own line's text (no line of it can be forged)."""
    lines: list[str] = []
    for block in blocks:
        # one line each, with no HTML tag (a Markdown viewer would render a stored <script>)
        text, title = (one_line(value).replace("<", "&lt;") for value in (block.text, block.title))
        if block.kind in HEADINGS:
            lines += ["#" * int(block.kind[1]) + f" {text}", ""]
        elif block.kind == "p":
            lines += [text, ""]
        elif block.kind == "pre":
            mark = fence(block.text)
            lines += ([f"{title}:", ""] if block.title else []) + [mark, block.text, mark, ""]
        elif block.kind == "table":
            head = "| " + " | ".join(one_line(h).replace("|", "\\|") for h in block.headers) + " |"
            rows = ["| " + " | ".join(markdown_cell(c) for c in row) + " |" for row in block.rows]
            lines += [head, "|" + "---|" * len(block.headers), *rows, ""]
        elif block.kind == "figure":
            lines += [f"### {title}", "", f"![{markdown_cell(title)}]({plots_dir}/{block.name})", "", f"*{text}*", ""]
    return "\n".join(lines)


CSS = """
body { font-family: -apple-system, 'Segoe UI', Helvetica, Arial, sans-serif; margin: 2em auto; max-width: 1150px;
       color: #1d1d1f; line-height: 1.45; padding: 0 1em; }
h1 { border-bottom: 2px solid #444; padding-bottom: .2em; }
h2 { margin-top: 1.8em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: .6em 0 1em; font-size: 13px; display: block; overflow-x: auto; }
th, td { border: 1px solid #ccc; padding: 3px 8px; text-align: right; }
th { background: #f0f0f3; }
td:first-child, th:first-child, td.t { text-align: left; }
details { margin: .4em 0; } summary { cursor: pointer; color: #333; }
tr.pass td { background: #eaf7ea; }
tr.fail td { background: #fbe3e3; }
figure { margin: 1em 0; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 13px; color: #555; }
pre { background: #f6f6f8; padding: .6em; font-size: 12px; white-space: pre-wrap; overflow-wrap: anywhere; }
.verdict-HOLDS { color: #17701f; } .verdict-FAILS { color: #b00020; } .verdict-UNDECIDED { color: #9a5b00; }
"""


def _html_inline(text: str) -> str:
    """A paragraph's text escaped, its ``**bold**`` runs as <strong>, the verdict's coloured by its class."""
    parts = html.escape(text).split("**")
    bold = "".join(f"<strong>{part}</strong>" if index % 2 else part for index, part in enumerate(parts))
    return re.sub(r"<strong>(Verdict: (\w+))</strong>", r'<strong class="verdict-\2">\1</strong>', bold)


NUMERIC = re.compile(r"^[-+]?[\d./]+( ± [\d.]+)?( \([-+]?[\d.]+( ± [\d.]+)?\))?( exact)?$")


def _cell(value: object) -> str:
    """A table cell: numbers right-aligned, text left-aligned."""
    text = str(value)
    cls = "" if NUMERIC.match(text) or text in ("-", "PASS", "FAIL") else ' class="t"'
    return f"<td{cls}>{html.escape(text)}</td>"


def render_html(blocks: Sequence[Block], title: str = "vprsnn-export verification report") -> str:
    body: list[str] = []
    for block in blocks:
        if block.kind in HEADINGS:
            body.append(f"<{block.kind}>{html.escape(block.text)}</{block.kind}>")
        elif block.kind == "p":
            body.append(f"<p>{_html_inline(block.text)}</p>")
        elif block.kind == "pre":
            pre = f"<pre>{html.escape(block.text)}</pre>"
            body.append(
                f"<details><summary>{html.escape(block.title)}</summary>{pre}</details>" if block.title else pre
            )
        elif block.kind == "table":
            head = "".join(f"<th>{html.escape(str(h))}</th>" for h in block.headers)
            rows = "".join(
                (f'<tr class="{status}">' if status else "<tr>") + "".join(map(_cell, row)) + "</tr>"
                for row, status in zip_longest(block.rows, block.status)
            )
            body.append(f"<table><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>")
        elif block.kind == "figure":
            data = base64.b64encode(block.image).decode("ascii")
            body.append(
                f"<h3>{html.escape(block.title)}</h3>"
                f'<figure><img alt="{html.escape(block.title)}" src="data:image/png;base64,{data}">'
                f"<figcaption>{html.escape(block.text)}</figcaption></figure>"
            )
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>'
        f"<style>{CSS}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n"
    )


def write_report(report: VerifyReport, out_dir: str | Path, *, write_json: bool = True) -> dict[str, Path]:
    """Write report.json (optionally), report.md with plots/*.png, and the self-contained report.html."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}
    if write_json:
        written["json"] = atomic_write_text(out / REPORT_JSON, json.dumps(report.to_dict(), indent=1) + "\n")
    blocks = blocks_of(report)
    for block in blocks:
        if block.kind == "figure":
            atomic_write_bytes(out / PLOTS_DIR / block.name, block.image)
    written["md"] = atomic_write_text(out / REPORT_MD, render_markdown(blocks))
    written["html"] = atomic_write_text(out / REPORT_HTML, render_html(blocks))
    return written
