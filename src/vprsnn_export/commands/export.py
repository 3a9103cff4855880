"""`vprsnn-export export`: write NIR, a Loihi-style description and ONNX, and say what each consumer computes.

``--check`` reads every written file back and runs it beside the project's simulators; ``--loihi-cores MxNxI`` alone
prints the Loihi-class core budget.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import textwrap
from pathlib import Path

from ..arguments import ascii_uint
from ..data.dataset import MAX_PLACES
from ..errors import InvalidValueError
from ..export.model import DEFAULT_BITS
from ..targets.nir_semantics import WTA_INHIBITION
from ..targets.registry import TARGETS
from ._common import add_data_options, add_runtime_options, format_table, integer, print_json

CHECK_COLUMNS = (("target", "target"), ("check", "check"), ("result", "result"), ("detail", "detail"))
LINE_WIDTH = 120  # the console output's lines; the full texts are in export.json (and --json)
DETAIL_WIDTH = 42  # a longer detail is cut in the table and printed whole under it, wrapped


def cut_cells(rows: list[dict], key: str, width: int) -> tuple[list[dict], list[tuple[int, str]]]:
    """``rows`` with every ``key`` cell longer than ``width`` cut to a note mark ``[n]``, and the notes (n, text)."""
    notes: list[tuple[int, str]] = []
    cut = []
    for row in rows:
        text = str(row.get(key, ""))
        if len(text) > width:
            notes.append((len(notes) + 1, text))
            text = f"{text[: width - 8].rstrip()}... [{len(notes)}]"
        cut.append({**row, key: text})
    return cut, notes


BUDGET_COLUMNS = (
    ("chip", "chip"),
    ("bits", "bits"),
    ("modules", "modules"),
    ("neurons_per_module", "neurons/module"),
    ("inputs", "inputs"),
    ("neurons_per_core", "neurons/core"),
    ("cores_per_module", "cores/module"),
    ("cores", "cores"),
    ("chips", "chips"),
    ("synapses", "synapses"),
    ("synapse_bits_per_core", "synapse bits/core"),
    ("synapse_bits_limit", "limit"),
)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("export", help="export a model to NIR, a Loihi-style description and ONNX")
    parser.add_argument("model", nargs="?", help="float checkpoint (train) or fixed-point model (quantize)")
    parser.add_argument("--to", default=",".join(TARGETS), help=f"comma-separated targets: {TARGETS.choices()}")
    parser.add_argument(
        "--out",
        metavar="DIR",
        help="output folder (new or empty; built whole, then put in place); required unless --loihi-cores",
    )
    parser.add_argument(
        "--loihi-cores",
        metavar="MxNxI",
        help="instead of exporting: the Loihi-class cores and synapses of M modules of N neurons with I inputs "
        "at 8, 4 and 2 bits (e.g. 24x400x1568)",
    )
    parser.add_argument("--force", action="store_true", help="replace an earlier export in --out")
    parser.add_argument(
        "--quantize",
        type=integer,
        metavar="BITS",
        help="float checkpoint only: quantise on the fly for loihi/onnx (per-neuron max-abs scales, float calibration)",
    )
    parser.add_argument(
        "--nir-inhibition",
        type=float,
        default=WTA_INHIBITION,
        help="with --nir-wta-node: strength k of the recurrent inhibitory WTA Linear, W[j, i] = -k theta_j "
        f"(default {WTA_INHIBITION})",
    )
    parser.add_argument(
        "--nir-wta-node",
        action="store_true",
        help="add a recurrent inhibitory WTA Linear to the NIR graph (default: none; the WTA is the readout rule "
        "in the metadata; snnTorch and Norse mishandle recurrent graphs)",
    )
    parser.add_argument(
        "--nir-no-wta-node", action="store_true", help="the default now (kept so that older commands still run)"
    )
    parser.add_argument(
        "--check", action="store_true", help="read every file back and run it beside the project's simulators"
    )
    parser.add_argument(
        "--nir-consumer",
        choices=("nirtorch", "snntorch", "norse", "norse-plain", "spikingjelly", "spikingjelly-plain"),
        default="nirtorch",
        help="with --check: the metadata-blind NIR consumer to measure (norse, spikingjelly: the consumers extra; "
        "-plain: without the file's consumer_settings)",
    )
    parser.add_argument(
        "--nir-tolerance",
        type=float,
        metavar="FRACTION",
        help="with --check: the share of decisions every installed float NIR consumer (+ readout rule) must share "
        "with the network, else the check fails (default: the file's float_consumers.decision_tolerance, 1.0 for "
        "files stated exact, 0.95 otherwise)",
    )
    parser.add_argument("--query", help="with --check: query traversal to present (default: synthetic spike trains)")
    parser.add_argument(
        "--check-samples", type=integer, default=16, help="with --check: presentations to run (0 = all queries)"
    )
    add_data_options(parser, data_required=False)
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of tables")
    add_runtime_options(parser)
    parser.set_defaults(handler=run)


def parse_shape(raw: str) -> tuple[int, int, int]:
    """'MxNxI' -> (modules, neurons per module, inputs), each a positive integer."""
    numbers = [ascii_uint(part.strip()) for part in raw.lower().split("x")]
    if len(numbers) != 3 or not all(numbers):
        raise InvalidValueError(f"--loihi-cores expects MODULESxNEURONSxINPUTS of positive integers, got {raw!r}")
    modules, neurons, inputs = (int(number or 0) for number in numbers)
    return modules, neurons, inputs


def print_budget(raw: str, as_json: bool) -> int:
    from ..targets.loihi_budget import budget_table

    budgets = budget_table(*parse_shape(raw), DEFAULT_BITS)
    rows = [dataclasses.asdict(budget) for budget in budgets]
    if as_json:
        print_json({"loihi_cores": rows})
    else:
        cells = [{key: f"{value:,}" if isinstance(value, int) else value for key, value in row.items()} for row in rows]
        print(format_table(cells, BUDGET_COLUMNS))
        for source in dict.fromkeys(budget.source for budget in budgets):
            print(f"  source: {source}")
    return 0


def run(args: argparse.Namespace) -> int:
    from ..device import resolve_device
    from ..runtime.consumer_gate import check_tolerance
    from ..runtime.exporting import export_and_check, load_source
    from ..runtime.exporting.checks import check_presentations
    from ..runtime.exporting.folder import MANIFEST_NAME, check_deploy_folder
    from ..runtime.exporting.source import integer_model

    if args.loihi_cores:
        if args.model or args.out:
            raise InvalidValueError("--loihi-cores takes no MODEL and no --out (it only prints the core budget)")
        return print_budget(args.loihi_cores, args.json)
    if not args.model or not args.out:
        raise InvalidValueError("export needs a MODEL and --out (or --loihi-cores MxNxI alone)")
    targets = TARGETS.parse_list(args.to, "--to")  # at least one registered target
    source = load_source(args.model)
    model = integer_model(source, args.quantize, targets)
    unused = [f"--{name.replace('_', '-')}" for name in ("query", "data", "subset", "places") if getattr(args, name)]
    if unused and not (args.check and args.query):  # the options of a check on real queries
        needs = "--query (the check's real queries)" if args.check else "--check (add --check, or leave them out)"
        raise InvalidValueError(f"{', '.join(unused)}: only used with {needs}")
    if not 0 <= args.check_samples <= MAX_PLACES:
        raise InvalidValueError(f"--check-samples expects 0 (all queries) to {MAX_PLACES}, got {args.check_samples}")
    out = Path(args.out)
    check_deploy_folder(out, overwrite=args.force)
    spikes, label = None, ""
    if args.check:
        spikes, label = check_presentations(
            source,
            args.query,
            data=args.data,
            subset=args.subset,
            places=args.places,
            samples=args.check_samples,
            progress=not args.quiet,
        )
    result = export_and_check(
        source,
        model,
        targets,
        out,
        inhibition=args.nir_inhibition,
        wta_node=args.nir_wta_node and not args.nir_no_wta_node,
        spikes=spikes,
        spikes_label=label,
        nir_consumer=args.nir_consumer,
        nir_tolerance=check_tolerance(args.nir_tolerance),
        device=resolve_device(args.device),
        overwrite=args.force,
        progress=not args.quiet,
    )
    if args.json:
        print_json(result.to_dict())
    else:
        for target, files in result.files.items():
            print(f"{target}: {', '.join(str(f.path) for f in files)}")
            if target in result.consumers:
                print(textwrap.fill(result.consumers[target], LINE_WIDTH, initial_indent="  ", subsequent_indent="  "))
        for estimate in (result.cost or {}).get("estimates", []):
            print(
                f"\nper query on {label}: {estimate['synaptic_events']:,.0f} synaptic events, {estimate['steps']:.0f} "
                f"steps; {estimate['chip']} estimate {estimate['energy_uj']:.1f} uJ, {estimate['latency_ms']:.2f} ms"
            )
        if result.checks is not None:
            print(f"\nchecks on {label}:")
            rows, notes = cut_cells([row.to_dict() for row in result.checks.rows], "detail", DETAIL_WIDTH)
            print(format_table(rows, CHECK_COLUMNS))
            for number, note in notes:
                print(textwrap.fill(note, LINE_WIDTH, initial_indent=f"  [{number}] ", subsequent_indent="      "))
        if not args.quiet:
            print(f"\nwrote {out / MANIFEST_NAME}", file=sys.stderr)
    return 0 if result.passed else 1
