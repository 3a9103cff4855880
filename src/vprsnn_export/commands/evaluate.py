"""`vprsnn-export evaluate`: the float network on a query traversal, every strategy and k."""

from __future__ import annotations

import argparse
import sys

import numpy as np

from ..checkpoint import load_checkpoint
from ..dataset import load_dataset
from ..device import resolve_device
from ..errors import InvalidValueError
from ._common import (
    RESULT_COLUMNS,
    add_query_options,
    add_runtime_options,
    format_table,
    parse_int_list,
    parse_velocity_grid,
    print_json,
)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("evaluate", help="evaluate a float checkpoint on a query traversal")
    parser.add_argument("checkpoint", help="checkpoint written by train")
    add_query_options(parser)
    parser.add_argument("--baseline", action="store_true", help="add the no-learning SAD baseline rows")
    add_runtime_options(parser)
    parser.set_defaults(handler=run)


def readout_options(args: argparse.Namespace, gamma: float):
    from ..runtime.evaluation import ReadoutOptions

    return ReadoutOptions(
        gamma=gamma,
        ks=parse_int_list(args.k, "--k"),
        rule=args.rule,
        velocity=args.velocity,
        velocity_candidates=parse_velocity_grid(args.velocity_search),
        tolerance=args.tolerance,
    )


def load_query_data(args: argparse.Namespace, ckpt, traversals: list[str]):
    """The data set for queries: options given here, else the checkpoint's source and selection."""
    subset, places = args.subset, args.places
    if subset is None and places is None:
        subset, places = ckpt.data.get("subset"), ckpt.data.get("places")
    return load_dataset(
        args.data or ckpt.data["source"],
        traversals,
        ckpt.config.preprocess,
        subset=subset,
        places=places,
        progress=not args.quiet,
    )


def run(args: argparse.Namespace) -> int:
    from ..runtime.evaluation import evaluate_float

    ckpt = load_checkpoint(args.checkpoint)
    options = readout_options(args, ckpt.config.assignment.gamma)
    traversals = [args.query] + ([t for t in ckpt.reference_traversals if t != args.query] if args.baseline else [])
    dataset = load_query_data(args, ckpt, traversals)
    if args.baseline and not np.array_equal(dataset.place_ids, ckpt.reference_place_ids):
        raise InvalidValueError("--baseline needs the query places to be the checkpoint's reference places")
    result = evaluate_float(
        ckpt,
        dataset.traversal(args.query),
        dataset.place_ids,
        args.query,
        options,
        device=resolve_device(args.device),
        state_isolation=False if args.no_state_isolation else None,
        reference_images={t: dataset.traversal(t) for t in ckpt.reference_traversals} if args.baseline else None,
    )
    if args.json:
        print_json(
            {
                "config": ckpt.config.to_dict(),
                "checkpoint": str(args.checkpoint),
                "query": args.query,
                "results": result["rows"],
                "spike_stats": result["spike_stats"],
            }
        )
    else:
        print(format_table(result["rows"], RESULT_COLUMNS))
        stats = result["spike_stats"]
        print(
            f"\nthreshold candidates per step: {stats['mean_candidates_per_step']:.1f} on average; "
            f"{100 * stats['multi_candidate_step_fraction']:.1f} % of steps have more than one",
            file=sys.stderr,
        )
    return 0
