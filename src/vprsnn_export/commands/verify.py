"""`vprsnn-export verify`: quantise, export and run every implementation; judge each bit width against float.

Every metric tolerance is judged on paired queries: holds (the interval lies inside the tolerance), fails
(entirely outside), undecided (it straddles). Exit codes: 0 when nothing fails, 1 when a check fails, 2 on bad
input, 3 with ``--strict`` when nothing fails but a check is undecided.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterable
from pathlib import Path

from ..data.dataset import MAX_PLACES, data_selection
from ..errors import EXIT_CHECK_FAILED, InvalidValueError
from ..io.checkpoint import Checkpoint, checkpoint_sha256, load_checkpoint
from ..runtime.results import VerifyReport
from ..targets.registry import TARGETS
from ._common import (
    add_bits_option,
    add_data_options,
    add_quantise_options,
    add_runtime_options,
    add_sequence_options,
    bit_widths,
    format_table,
    integer,
    non_empty,
    print_json,
    quantise_options,
    refuse_window_beside_truth,
    sequence_options,
)

#: `--strict`: the exit code of a run in which nothing fails but a paired check is undecided.
EXIT_UNDECIDED = 3


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "verify",
        help="quantise and export at several bit widths; check every implementation against the float network",
        description="For each bit width: quantise, run the integer simulator, the ONNX graph, the NIR and Loihi-style "
        "files read back and the reference stepper on the float network's very input spikes; compare exactly across "
        "implementations and against float, each metric judged on paired queries (holds / fails / undecided); "
        "write report.json, report.md and report.html. Exit 0: nothing fails (undecided included); 1: a check "
        "fails; 2: bad input; 3: with --strict, nothing fails but a check is undecided.",
    )
    parser.add_argument("checkpoints", nargs="+", metavar="CKPT", help="float checkpoint(s) written by train")
    add_bits_option(parser)
    parser.add_argument("--query", required=True, help="query traversal name")
    add_data_options(parser, data_required=False)
    add_sequence_options(parser, default_k="1,3,5", old_window_option="--gt-tolerance", json=False)
    checks = parser.add_argument_group("checks")
    checks.add_argument(
        "--tolerance",
        type=non_empty,
        metavar="KEY=VALUE,...",
        help="override tolerances, e.g. r_at_100p=0.01,accuracy=0.02,auc_pr=0.02 (fractions; 'off' disables); "
        "keys: accuracy, r_at_100p, auc_pr, p_at_100r, winner_agreement, top1_agreement, saturations, query_slack "
        "(docs/verify.md)",
    )
    checks.add_argument(
        "--strict",
        action="store_true",
        help=f"exit {EXIT_UNDECIDED} when nothing fails but a paired check is undecided (its interval straddles "
        "its tolerance: too few queries to decide); without it an undecided check exits 0 with a note",
    )
    checks.add_argument(
        "--reference-queries",
        type=integer,
        default=3,
        help="queries also run on the slow reference stepper (default 3; 0 = none)",
    )
    checks.add_argument(
        "--targets",
        type=non_empty,
        default=",".join(TARGETS),
        help=f"exported targets to read back and run: some of {TARGETS.choices()} (default: %(default)s; or none)",
    )
    add_quantise_options(parser)
    parser.add_argument(
        "--seeds", type=integer, help="train N networks (seeds 1..N) with CKPT's config and data; mean ± std"
    )
    parser.add_argument(
        "--report",
        required=True,
        metavar="DIR",
        help="folder for report.json, report.md, report.html (regenerated on each run)",
    )
    parser.add_argument("--json", action="store_true", help="print the verdict and summary as JSON instead of a table")
    add_runtime_options(parser)
    parser.set_defaults(handler=run)


def folder_name(label: str, index: int) -> str:
    """A file-system-safe folder for one network's exports: its label, else its position."""
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in label).strip("._")
    return f"{index + 1:02d}-{safe}" if safe else f"{index + 1:02d}"


def verdict_rows(report: VerifyReport) -> list[dict]:
    """One row per network and bit width for the terminal table: the report's verdict table's cells."""
    from ..runtime.report.labels import results, verdict_cells

    return [verdict_cells(*item) for item in results(report)]


def paired_rows(report: VerifyReport, as_json: bool = False) -> list[dict]:
    """The paired table of every network and bit width: every judged check and every readout's accuracy
    (``as_json``: every paired check, as its JSON object)."""
    from ..runtime.report.labels import paired_cells, results, shown_paired

    return [
        {"network": label, "bits": result.bits, **(check.to_dict() if as_json else paired_cells(check))}
        for label, _, result in results(report)
        for check in (result.paired if as_json else shown_paired(result.paired))
    ]


def conclusion(report: VerifyReport, strict: bool) -> tuple[str, int]:
    """The last line and the exit code: FAILS (1), UNDECIDED (0, or 3 with --strict) or HOLDS (0), with the float
    networks that do not recognise places named (the exit code is the verdict's)."""
    line, code = "HOLDS: every check holds at every bit width", 0
    if report.verdict == "fails":
        line = f"FAILS: {len(report.runs) - report.n_passed} of {len(report.runs)} network(s) fail a check"
        code = EXIT_CHECK_FAILED
    elif report.verdict == "undecided":
        checks = [c for run in report.runs for r in run.bits for c in r.paired if c.verdict == "undecided"]
        needed = [c.queries_to_decide for c in checks if c.queries_to_decide]
        more = f" (about {max(needed)} queries would decide them)" if needed else ""
        code = EXIT_UNDECIDED if strict else 0
        line = (
            f"UNDECIDED: nothing fails, but {len(checks)} paired check(s) straddle their tolerance{more}; "
            f"exit {code}" + ("" if strict else f" ({EXIT_UNDECIDED} with --strict)")
        )
    if report.degenerate:
        line += f"; DEGENERATE float network ({report.degenerate}): a width that holds keeps nothing worth keeping"
    return line, code


MAX_SEEDS = 1000  # networks trained by one verify run


def run(args: argparse.Namespace) -> int:
    from ..device import resolve_device
    from ..runtime.report import write_report
    from ..runtime.report.labels import PAIRED_COLUMNS, VERDICT_COLUMNS
    from ..runtime.verify import Runtime, VerifiedNetwork, VerifyOptions, build_report, verify_checkpoint
    from ..runtime.verify.checks import parse_tolerances
    from ..runtime.verify.networks import seed_networks, verify_data

    started = time.perf_counter()
    progress = not args.quiet
    if args.seeds is not None and (not 1 <= args.seeds <= MAX_SEEDS or len(args.checkpoints) != 1):
        raise InvalidValueError(
            f"--seeds N needs N from 1 to {MAX_SEEDS} and exactly one CKPT (the template whose config and data are used)"
        )
    if not 0 <= args.reference_queries <= MAX_PLACES:
        raise InvalidValueError(f"--reference-queries expects 0 to {MAX_PLACES}, got {args.reference_queries}")
    device = resolve_device(args.device)
    out = Path(args.report)
    stems = [Path(p).stem for p in args.checkpoints]
    templates = [
        (stem if stems.count(stem) == 1 else f"{stem} ({i + 1})", load_checkpoint(p), Path(p))
        for i, (stem, p) in enumerate(zip(stems, args.checkpoints, strict=True))
    ]
    template = templates[0][1]
    networks: Iterable[tuple[str, Checkpoint, Path]] = templates
    options = VerifyOptions(
        bits=tuple(dict.fromkeys(bit_widths(args))),  # first: a bad --bits is the error reported
        readout=sequence_options(args),
        quantise=quantise_options(args),
        reference_queries=args.reference_queries,
        targets=TARGETS.parse_list(args.targets, "--targets", allow_none=True),
        tolerances=parse_tolerances(args.tolerance),
    )
    source, subset, places = data_selection(template.data, args.data, args.subset, args.places)
    refuse_window_beside_truth(args, template, args.query)
    cache: dict = {}
    if args.seeds is not None:
        dataset, _ = verify_data(template, args.query, source, subset, places, progress, cache)  # training places
        networks = seed_networks(template, args.seeds, dataset, source, subset, places, out, args.device, progress)
    settings = {
        **options.to_dict(template.config),
        "query": args.query,
        "data": source,
        "subset": subset,
        "places": places,
        "seeds": args.seeds,
        "checkpoints": list(args.checkpoints),
        "device": args.device,
    }
    command = ["vprsnn-export", *getattr(args, "argv", ["verify", *args.checkpoints])]  # as given (cli.main's argv)
    runs = []
    for index, (label, ckpt, path) in enumerate(networks):
        src, sub, plc = data_selection(ckpt.data, args.data, args.subset, args.places)
        dataset, reference_images = verify_data(ckpt, args.query, src, sub, plc, progress, cache)
        if index == 0 and options.readout.warning(dataset.place_ids):
            print(
                "note: the queries are not consecutive places: k > 1 metrics are reported but not judged "
                "(their windows mix unrelated places)",
                file=sys.stderr,
            )
        query = dataset.query(args.query, ckpt.reference_traversals, args.match_window)
        if query.truth.source:  # the report says what the queries were scored against
            settings["ground_truth"] = query.truth.source
        settings["truth"] = query.truth.label
        references = None if options.quantise.calibration == "float" else reference_images
        network = VerifiedNetwork(ckpt, checkpoint_sha256(path), references, label, str(path))
        runtime = Runtime(device, progress, out / "exports" / folder_name(label, index))
        runs.append(verify_checkpoint(network, query, options, runtime))
        report = build_report(runs, settings, command=command, seconds=time.perf_counter() - started)
        written = write_report(report, out)  # after every network: a long --seeds run leaves a usable report
    line, code = conclusion(report, args.strict)
    if args.json:
        print_json(
            {
                "passed": report.passed,
                "verdict": report.verdict,
                "truth": settings.get("truth"),
                "exit_code": code,
                "report": {k: str(v) for k, v in written.items()},
                "summary": report.summary.to_dict(),
                "paired": paired_rows(report, as_json=True),
            }
        )
    else:
        print(format_table(verdict_rows(report), VERDICT_COLUMNS))
        for run in report.runs:
            if run.float.cost is not None:
                print(f"{run.label}: {run.float.cost.line()}", file=sys.stderr)
        level = 100 * options.statistics.confidence
        print(
            f"\npaired checks (float and deployed on the same queries; Δ = deployed - float, {level:g} % interval; "
            "flips: float right/deployed wrong and the reverse):"
        )
        print(format_table(paired_rows(report), (("network", "network"), ("bits", "bits"), *PAIRED_COLUMNS)))
        print(f"\nscored against the {settings['truth']}" if "truth" in settings else "")
        print(f"{line}; report: {written['html']}")
    return code
