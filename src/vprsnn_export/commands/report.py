"""`vprsnn-export report`: rebuild report.md and report.html from report.json; combine runs into mean ± std."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import InvalidValueError
from ._common import add_threads_option


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "report",
        help="rebuild the verification report from report.json files; several are combined into mean ± std",
        description="Each RUN_DIR is a folder written by `verify` (or its report.json). One RUN_DIR: report.md and "
        "report.html are rebuilt in place (or in --out). Several: their networks are pooled into one report "
        "(mean ± std over all of them) written to --out, report.json included. Nothing is re-run.",
    )
    parser.add_argument("runs", nargs="+", metavar="RUN_DIR", help="verify output folder(s) or report.json file(s)")
    parser.add_argument(
        "--out",
        help="output folder (required with several RUN_DIRs; default: the one RUN_DIR; report.md/html there are regenerated)",
    )
    parser.add_argument(
        "--allow-mixed",
        action="store_true",
        help="pool reports made on other data, bit widths or readout settings (refused otherwise)",
    )
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    add_threads_option(parser)
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from ..runtime.report import combine_reports, load_report, report_path, write_report

    sources = [str(report_path(p)) for p in args.runs]
    if len(set(sources)) != len(sources):
        raise InvalidValueError("the same report is named twice")
    reports = [load_report(p) for p in args.runs]
    if len(reports) > 1 and not args.out:
        raise InvalidValueError("combining several reports needs --out DIR")
    here = report_path(args.runs[0]).parent
    out = Path(args.out) if args.out else here
    combined = combine_reports(reports, sources, allow_mixed=args.allow_mixed)
    written = write_report(combined, out, write_json=len(reports) > 1 or out.resolve() != here.resolve())
    if not args.quiet:
        verdict = "PASS" if combined.passed else "FAIL"
        print(f"{verdict}: {combined.n_passed} of {len(combined.runs)} network(s) pass every check", file=sys.stderr)
        for kind, path in written.items():
            print(f"{kind}: {path}")
    return 0
