"""`vprsnn-export simulate`: a fixed-point model on the bit-exact integer simulator, read out like `evaluate`."""

from __future__ import annotations

import argparse
import sys

from ..errors import InvalidValueError
from ..export.model import load_fixed_point
from ..io.checkpoint import checkpoint_sha256, load_checkpoint
from ._common import (
    RESULT_COLUMNS,
    add_query_options,
    add_runtime_options,
    format_table,
    load_query,
    print_json,
    run_options,
)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("simulate", help="run a fixed-point model on the integer simulator")
    parser.add_argument("model", help="fixed-point model written by quantize")
    add_query_options(parser)
    parser.add_argument(
        "--compare",
        metavar="CHECKPOINT",
        help="the float source checkpoint: also report how often the integer network picks the float network's winner",
    )
    add_runtime_options(parser)
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from ..runtime.evaluation import evaluate_fixed_point

    model = load_fixed_point(args.model)
    float_checkpoint = None
    if args.compare:
        float_checkpoint = load_checkpoint(args.compare)
        if checkpoint_sha256(args.compare) != model.source_sha256:
            raise InvalidValueError(
                f"--compare {args.compare}: not the checkpoint this model was quantised from (sha256 differs)"
            )
    options, _, query = load_query(args, model)
    truth = query.truth
    result = evaluate_fixed_point(
        model,
        query.images,
        query.place_ids,
        args.query,
        options,
        float_checkpoint=float_checkpoint,
        truth=truth,
        **run_options(args),
    )
    if args.json:
        print_json(
            {
                "config": model.config.to_dict(),
                "model": str(args.model),
                "source_sha256": model.source_sha256,
                "query": args.query,
                "truth": truth.label,
                "bits": model.bits,
                "threads": args.threads,
                "quantisation": model.quantisation.to_dict(),
                "saturations": result.saturations,
                "max_current": result.max_current,
                **result.to_dict(),
            }
        )
    else:
        print(format_table(result.rows, (("calibration", "calibration"), *RESULT_COLUMNS)))
        print(f"scored against the {truth.label}")
        stats = result.spike_stats
        print(
            f"\n{model.bits}-bit model; saturation events: {result.saturations}; threshold candidates per step: "
            f"{stats.mean_candidates_per_step:.1f} on average, {100 * stats.multi_candidate_step_fraction:.1f} % "
            "of steps have more than one",
            file=sys.stderr,
        )
        if result.cost is not None:
            print(result.cost.line(), file=sys.stderr)
        if (agreement := result.winner_agreement) is not None:
            print(
                f"same spikes as the float network on {100 * agreement['all_steps']:.2f} % of steps "
                f"({100 * agreement['active_steps']:.2f} % of the steps where either spikes)",
                file=sys.stderr,
            )
    return 0
