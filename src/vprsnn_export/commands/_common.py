"""Options and helpers shared by several subcommands."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from dataclasses import fields
from functools import reduce
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..arguments import ascii_int
from ..config import PRESETS, Config, preset
from ..data.dataset import Dataset, dataset_files, load_selection, window_beside_truth
from ..data.groundtruth import ground_truth_files
from ..errors import InvalidValueError
from ..export.model import DEFAULT_BITS, check_bits
from ..export.quantize import SCALE_METHODS
from ..io.fileio import check_output, parse_json
from ..readout.rules import RULES
from ..readout.search import DEFAULT_PATIENCE, SearchWindow
from ..readout.sequence import MAX_K, MAX_VELOCITY, SequenceOptions, option_flag
from ..readout.velocity import VELOCITY_ESTIMATES, causal_estimates

if TYPE_CHECKING:
    from ..data.truth import Query
    from ..export.model import FixedPointModel
    from ..export.quantize import QuantiseOptions
    from ..io.checkpoint import Checkpoint

    Network = Checkpoint | FixedPointModel


def integer(text: str) -> int:
    """An option's integer: ASCII decimal digits with an optional '-' (``int()`` also takes '٣' and '1_0')."""
    value = ascii_int(text.strip())
    if value is None:
        raise ValueError(text)  # argparse: "invalid integer value"
    return value


def non_empty(text: str) -> str:
    """argparse type: any text but an empty or blank one (``--data ''`` is a slip, not the current folder)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("empty value")
    return text


def add_data_options(parser: argparse.ArgumentParser, *, data_required: bool) -> None:
    group = parser.add_argument_group("data")
    group.add_argument(
        "--data",
        type=non_empty,
        required=data_required,
        help="place manifest CSV (or its folder), or 'synthetic[:N]' for the embedded synthetic route",
    )
    selection = group.add_mutually_exclusive_group()
    selection.add_argument("--subset", type=non_empty, help="CSV with a place_id column: the places to use, in order")
    selection.add_argument("--places", type=non_empty, help="START:COUNT[:STRIDE] consecutive place ids")


def add_query_options(parser: argparse.ArgumentParser) -> None:
    add_data_options(parser, data_required=False)
    parser.add_argument("--query", required=True, help="query traversal name")
    add_sequence_options(parser)
    parser.add_argument(
        "--no-state-isolation", action="store_true", help="carry neuron state across queries (spillover ablation)"
    )


DEFAULT_BITS_TEXT = ",".join(map(str, DEFAULT_BITS))


def add_bits_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--bits", default=DEFAULT_BITS_TEXT, help=f"weight bit widths, each 2..8 (default {DEFAULT_BITS_TEXT})"
    )


def bit_widths(args: argparse.Namespace) -> list[int]:
    """The widths of --bits, in the order given; InvalidValueError naming --bits or an unsupported width."""
    return [check_bits(b) for b in parse_int_list(args.bits, "--bits")]


#: The help of each quantisation flag: quantize and verify add them with :func:`add_quantise_options`.
QUANTISE_HELP = {
    "--per-tensor": "one weight scale per module, shared by its neurons (a single network: one for all its neurons)",
    "--per-neuron": "one weight scale per neuron (the default)",
    "--scale": "weight scale: max (max-abs, no weight clips) or mse (minimum squared error; large weights may clip)",
    "--fold-thresholds": "choose per-neuron scales so that all neurons share one integer threshold "
    "(not with --per-tensor)",
    "--reuse-float-calibration": "keep the float network's S^R instead of recalibrating on the integer simulator "
    "(no reference images needed)",
    "--non-leaky": "deploy without the leak (beta = 1, decay_dv = 0: V <- V + a): every float NIR consumer then "
    "computes the model exactly; recalibrated on the integer simulator (docs/targets.md section 1.4 gives its cost)",
}


def add_quantise_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("quantisation")
    scales = group.add_mutually_exclusive_group()
    for flag in ("--per-tensor", "--per-neuron"):
        scales.add_argument(flag, action="store_true", help=QUANTISE_HELP[flag])
    group.add_argument("--scale", choices=SCALE_METHODS, default=SCALE_METHODS[0], help=QUANTISE_HELP["--scale"])
    for flag in ("--fold-thresholds", "--reuse-float-calibration", "--non-leaky"):
        group.add_argument(flag, action="store_true", help=QUANTISE_HELP[flag])


def quantise_options(args: argparse.Namespace) -> QuantiseOptions:
    from ..export.quantize import QuantiseOptions

    return QuantiseOptions(
        per_neuron=not args.per_tensor,
        scale_method=args.scale,
        fold_thresholds=args.fold_thresholds,
        calibration="float" if args.reuse_float_calibration else "deployed",
        non_leaky=args.non_leaky,
    )


def add_threads_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--threads",
        type=integer,
        metavar="N",
        help="CPU threads for torch (default: OMP_NUM_THREADS, else 1: more threads than free cores "
        "slow a shared machine down 10-20x)",
    )
    parser.add_argument(
        "--memory-limit",
        metavar="SIZE",
        help="memory a run may need, e.g. 512M or 8G: a run predicted to need more stops before it starts "
        "(default: VPRSNN_MEMORY_LIMIT, else 90%% of the available memory; docs/scale.md)",
    )


def add_runtime_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--device", default="auto", help="auto (GPU when present), cpu or cuda")
    add_threads_option(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


#: The help of each SequenceOptions field's option.
SEQUENCE_HELP = {
    "ks": "sequence lengths, e.g. 1,3,5 (the sequence strategy aggregated for k > 1)",
    "rule": "aggregation rule: " + "; ".join(f"{r.name}: {r.description}" for r in RULES.values()),
    "velocity": "places per query frame (negative: reversed)",
    "velocity_candidates": "estimate the velocity from the query stream over this grid LO:HI:STEP instead of using "
    "--velocity (negative values allowed: -2:2:0.1)",
    "velocity_estimate": "with --velocity-search: "
    + "; ".join(f"{e.name}: {e.description}" for e in VELOCITY_ESTIMATES.values()),
    "velocity_span": "smooth, track: recent windows whose scores are summed",
    "velocity_length": "smooth, track: frames per scored trajectory (default 3k, 2k)",
    "velocity_memory": "smooth, track: recent frames whose mean is divided out (0: none)",
    "velocity_lag": "smooth: next windows also summed, i.e. frames each decision waits for (default 2k-1)",
    "tolerance": "a prediction within +-N places of the truth is correct",
}
#: The help a causal stream (localize) shows instead: one k, the causal estimates only (the fixed-lag one and its
#: --velocity-lag wait for later frames, so a stream does not offer them).
STREAM_HELP = {
    **{name: text.replace("smooth, track: ", "track: ") for name, text in SEQUENCE_HELP.items()},
    "ks": "the sequence length of every decision (one k; the sequence strategy aggregated for k > 1)",
    "velocity_estimate": "with --velocity-search: "
    + "; ".join(f"{name}: {VELOCITY_ESTIMATES.get(name).description}" for name in causal_estimates()),
    "velocity_lag": argparse.SUPPRESS,
}


def add_sequence_options(
    parser: argparse.ArgumentParser,
    *,
    default_k: str | None = None,
    stream: bool = False,
    old_window_option: str | None = "--tolerance",
    json: bool = True,
) -> None:
    """One option per :class:`SequenceOptions` field, None unless given; ``stream``: localize's causal estimates."""
    group = parser.add_argument_group("sequence")
    estimates = causal_estimates() if stream else VELOCITY_ESTIMATES.names()
    for item in fields(SequenceOptions):
        flag = option_flag(item.name)
        default = default_k if item.name == "ks" and default_k else item.default
        if item.name == "velocity_estimate" and stream:
            default = estimates[0]
        shown = ",".join(map(str, default)) if isinstance(default, tuple) else default
        kind: dict[str, Any] = {"type": integer, "metavar": "N"}
        if item.name in ("ks", "velocity_candidates"):
            kind = {"metavar": ("N" if stream else "LIST") if item.name == "ks" else "LO:HI:STEP"}
        elif item.name == "velocity":
            kind = {"type": float}
        elif item.name in ("rule", "velocity_estimate"):
            kind = {"choices": RULES.names() if item.name == "rule" else estimates}
        note = "" if shown is None else f" (default {shown})"
        text = (STREAM_HELP if stream else SEQUENCE_HELP)[item.name]
        group.add_argument(flag, help=text if text == argparse.SUPPRESS else text + note, **kind)
    if old_window_option:
        group.add_argument(old_window_option, dest="renamed_window", help=argparse.SUPPRESS)
    parser.set_defaults(old_window_option=old_window_option, default_k=default_k, stream=stream)
    if json:
        group.add_argument("--json", action="store_true", help="print one JSON object instead of a table")


def given_sequence_options(args: argparse.Namespace) -> dict[str, Any]:
    """The sequence options given on the command line, parsed (``--k``, ``--velocity-search``), by field name."""
    if getattr(args, "renamed_window", None) is not None:
        raise InvalidValueError(
            f"{args.old_window_option}: renamed to --match-window (the ground-truth window in places); "
            "verify's --tolerance sets pass/fail limits"
        )
    raw = {f.name: getattr(args, option_flag(f.name)[2:].replace("-", "_")) for f in fields(SequenceOptions)}
    given = {name: value for name, value in raw.items() if value is not None}
    if "ks" in given or args.default_k:
        given["ks"] = parse_int_list(given.get("ks", args.default_k), "--k")
    if "velocity_candidates" in given:
        given["velocity_candidates"] = parse_velocity_grid(given["velocity_candidates"])
        if max(given.get("ks", (1,))) == 1:
            raise InvalidValueError(
                "--velocity-search estimates the velocity of k-frame sequences; at k = 1 there is none to "
                "estimate: give a --k above 1 or leave --velocity-search out"
            )
    if args.stream and "velocity_candidates" in given and "velocity_estimate" not in given:
        given["velocity_estimate"] = causal_estimates()[0]
    return given


def sequence_options(args: argparse.Namespace) -> SequenceOptions:
    return SequenceOptions(**given_sequence_options(args))


#: The config options of train: flag -> (config key, help; "{}" is the default config's value).
CONFIG_OPTIONS = {
    "--seed": ("seed", "seed for weights, shuffles and every spike (default: the preset's, {})"),
    "--epochs": ("train.epochs", "training epochs (default: the preset's, {})"),
    "--timesteps": (
        "encoder.timesteps",
        "presentation window T of calibration, queries and deployment, and of training unless train.timesteps "
        "is set (default: the preset's, {})",
    ),
    "--neurons": ("network.n_neurons", "excitatory neurons N_exc (default: the preset's, {})"),
    "--module-size": (
        "train.module_size",
        "places per module: one network per region of this many consecutive places, trained side by side "
        "(0, the default: one network for all places)",
    ),
}
#: The ablation switches of train: flag -> (config key, what it switches off).
ABLATIONS = {
    "--no-wta": ("network.wta", "hard winner-take-all"),
    "--no-homeostasis": ("homeostasis.enabled", "homeostasis"),
    "--no-patch-norm": ("preprocess.patch_norm", "image patch normalisation"),
    "--no-weight-norm": ("stdp.weight_norm", "column L2 weight normalisation"),
    "--no-state-isolation": ("network.state_isolation", "state reset between presentations"),
}


def add_config_options(parser: argparse.ArgumentParser) -> None:
    """--preset, the :data:`CONFIG_OPTIONS`, --set and the :data:`ABLATIONS`, each stored under its config key."""
    group = parser.add_argument_group("configuration (defaults: the paper's text with DoG ON/OFF inputs)")
    group.add_argument(
        "--preset",
        choices=sorted(PRESETS),
        help="starting configuration: dog (the default: illumination-invariant DoG ON/OFF input channels, "
        "docs/model.md), paper (the paper's patch-normalised intensity input) or lean (one neuron per place in "
        "modules of 100, learnt at T=300 and run at T=80: a tenth of the default's synaptic events per query, "
        "docs/results/cost.md); the options below apply on top",
    )
    base = Config()
    for flag, (key, text) in CONFIG_OPTIONS.items():
        default = reduce(getattr, key.split("."), base)
        metavar = flag[2:].upper().replace("-", "_")
        group.add_argument(flag, dest=key, type=integer, metavar=metavar, help=text.format(default))
    group.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="any config value by dotted name, e.g. --set stdp.a_plus=1e-3 (repeatable)",
    )
    for flag, (key, what) in ABLATIONS.items():
        group.add_argument(flag, dest=key, action="store_false", default=None, help=f"ablation: switch off {what}")


def config_from_args(args: argparse.Namespace) -> Config:
    keys = [key for key, _ in (*CONFIG_OPTIONS.values(), *ABLATIONS.values())]
    overrides = {key: getattr(args, key) for key in keys if getattr(args, key) is not None}
    for item in args.set:
        key, sep, raw = item.partition("=")
        if not sep:
            raise InvalidValueError(f"--set expects KEY=VALUE, got {item!r}")
        overrides[key.strip()] = parse_value(raw.strip())
    return (preset(args.preset) if args.preset else Config()).replace(**overrides)


def parse_value(raw: str) -> Any:
    """A --set value: JSON when it parses as JSON (numbers, true/false, null, lists), else the string."""
    try:
        return parse_json(raw, f"--set/--grid value {raw[:40]!r}")
    except json.JSONDecodeError:
        return raw


MAX_VELOCITY_CANDIDATES = 10_000


def parse_int_list(raw: str, option: str) -> tuple[int, ...]:
    """``"1,3,5"`` -> (1, 3, 5): integers from 1 to :data:`MAX_K`; InvalidValueError naming the option otherwise."""
    parsed = tuple(ascii_int(v.strip()) for v in raw.split(",") if v.strip())
    values = tuple(v for v in parsed if v is not None)
    if len(values) < len(parsed) or not values or min(values) < 1 or max(values) > MAX_K:
        expected = "comma-separated integers" if len(values) < len(parsed) else f"integers from 1 to {MAX_K}"
        raise InvalidValueError(f"{option} expects {expected}, got {raw!r}")
    return values


def parse_names(raw: str, option: str) -> list[str]:
    names = [v.strip() for v in raw.split(",") if v.strip()]
    if not names:
        raise InvalidValueError(f"{option} needs at least one traversal name")
    return names


def parse_velocity_grid(raw: str) -> tuple[float, ...]:
    try:
        lo, hi, step = (float(v) for v in raw.split(":"))
        finite = all(math.isfinite(v) for v in (lo, hi, step)) and max(abs(lo), abs(hi)) <= MAX_VELOCITY
        expected = "" if finite else f"finite velocities from -{MAX_VELOCITY:g} to {MAX_VELOCITY:g}"
    except ValueError:
        expected = "LO:HI:STEP"
    if expected:
        raise InvalidValueError(f"--velocity-search expects {expected}, got {raw!r}")
    if step <= 0 or hi < lo:
        raise InvalidValueError(f"--velocity-search needs LO <= HI and STEP > 0, got {raw!r}")
    count = int(round((hi - lo) / step)) + 1
    if count > MAX_VELOCITY_CANDIDATES:
        raise InvalidValueError(
            f"--velocity-search {raw!r} gives {count} velocities; at most {MAX_VELOCITY_CANDIDATES} (use a larger STEP)"
        )
    return tuple(round(lo + i * step, 10) for i in range(count))


def print_json(payload: dict) -> None:
    print(json.dumps(payload, indent=2))


def format_table(rows: Sequence[dict], columns: Sequence[tuple[str, str]]) -> str:
    """Plain text table; floats in [0, 1] metric columns are shown as percentages."""

    def cell(key: str, value: object) -> str:
        if not isinstance(value, float):
            return str(value)
        return f"{100 * value:6.2f}" if key in PERCENT_KEYS else f"{value:.4g}"

    cells = [[title for _, title in columns], *([cell(key, row.get(key, "")) for key, _ in columns] for row in rows)]
    widths = [max(len(r[i]) for r in cells) for i in range(len(columns))]
    out = ["  ".join(c.rjust(w) for c, w in zip(r, widths, strict=True)) for r in cells]
    out.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(out)


PERCENT_KEYS = {"accuracy", "p_at_100r", "r_at_100p", "auc_pr", "in_region"}
RESULT_COLUMNS = (
    ("strategy", "strategy"),
    ("k", "k"),
    ("accuracy", "acc %"),
    ("p_at_100r", "P@100R %"),
    ("r_at_100p", "R@100P %"),
    ("auc_pr", "AUC-PR %"),
    ("n_queries", "queries"),
)


def refuse_window_beside_truth(args: argparse.Namespace, network: Network, query: str) -> None:
    """--match-window on a folder with a ground-truth file of (reference, query): refused before any image loads."""
    source = args.data if args.data is not None else network.data.get("source")
    folder = Path(source) if source else None
    if not args.match_window or folder is None or not folder.is_dir():
        return
    if found := [p for ref in network.reference_traversals for p, _ in ground_truth_files(folder, ref, query)]:
        raise window_beside_truth(args.match_window, found[0])


def query_data(
    args: argparse.Namespace, network: Network, query: str | None = None, outputs: Sequence = (), inputs: tuple = ()
) -> Dataset:
    """The data set of --data/--subset/--places, else the one ``network`` records: ``query``, else its references;
    ``outputs`` checked against ``inputs`` before any image loads, then against the data set's files too."""
    for output in outputs:
        check_output(output, inputs=inputs)
    if query is not None:
        refuse_window_beside_truth(args, network, query)
    dataset = load_selection(
        network.data,
        list(network.reference_traversals) if query is None else [query],
        network.config.preprocess,
        source=args.data,
        subset=args.subset,
        places=args.places,
        progress=not args.quiet,
    )
    for output in outputs:
        check_output(output, inputs=(*inputs, *dataset_files(dataset, args.subset, network.data.get("subset"))))
    return dataset


def load_query(
    args: argparse.Namespace, network: Network, outputs: Sequence = (), inputs: tuple = ()
) -> tuple[SequenceOptions, Dataset, Query]:
    """evaluate and simulate: the sequence options, the data and the --query of ``network`` (a warning printed)."""
    options = sequence_options(args)
    dataset = query_data(args, network, args.query, outputs, inputs)
    query = dataset.query(args.query, network.reference_traversals, args.match_window)
    if warning := options.warning(dataset.place_ids):
        print(f"warning: {warning}", file=sys.stderr)
    return options, dataset, query


def run_options(args: argparse.Namespace) -> dict[str, Any]:
    """The keywords of evaluate's and simulate's evaluation: --device, --no-state-isolation and --quiet."""
    from ..device import resolve_device

    state_isolation = False if args.no_state_isolation else None
    return {"device": resolve_device(args.device), "state_isolation": state_isolation, "progress": not args.quiet}


def positive_int(text: str) -> int:
    """An ASCII decimal integer >= 1 (argparse type: '1_0', '١٠' and '0' are refused)."""
    if not (text.isascii() and text.isdigit() and int(text) >= 1):
        raise argparse.ArgumentTypeError(f"expected a positive whole number, got {text!r}")
    return int(text)


def add_search_options(parser: argparse.ArgumentParser) -> None:
    """--search-window and --patience: track within a window of places (localize --frames, evaluate)."""
    search = parser.add_argument_group("search window (docs/localize.md)")
    search.add_argument(
        "--search-window",
        type=positive_int,
        metavar="PLACES",
        help="run only the modules whose places lie within PLACES places around the last accepted place (one WTA "
        "over them); the first frame, and the frame after --patience frames without an accepted decision, run the "
        "whole route (an ensemble on the float network or the integer simulator)",
    )
    search.add_argument(
        "--patience",
        type=positive_int,
        metavar="N",
        help="with --search-window: frames in a row without an accepted decision before the whole route runs "
        f"again (default {DEFAULT_PATIENCE})",
    )
    search.add_argument(
        "--follow-within",
        type=positive_int,
        metavar="PLACES",
        help="with --search-window: an unaccepted decision within PLACES places of where the window expected it "
        "moves the window there and is no miss (fewer re-localisations; a kidnapped robot is found later)",
    )
    search.add_argument(
        "--lost-after",
        type=positive_int,
        metavar="N",
        help="with --search-window: after N window frames in a row without an accepted decision, followed ones "
        "included, the robot is lost: the recent frames are forgotten and the whole route runs until a decision is "
        "accepted (with --follow-within, a kidnapped robot is found sooner)",
    )


def search_window(args: argparse.Namespace) -> SearchWindow | None:
    """The SearchWindow of --search-window/--patience (None: the whole route every frame)."""
    if args.search_window is None and any(v is not None for v in (args.patience, args.follow_within, args.lost_after)):
        raise InvalidValueError("--patience, --follow-within and --lost-after are for --search-window")
    if args.search_window is None:
        return None
    return SearchWindow(args.search_window, args.patience or DEFAULT_PATIENCE, args.follow_within, args.lost_after)
