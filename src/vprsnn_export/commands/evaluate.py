"""`vprsnn-export evaluate`: the float network on a query traversal, every strategy and k."""

from __future__ import annotations

import argparse
import sys

from ..cluster import CLUSTER_HELP, parse_cluster
from ..data.dataset import load_selection, select_places
from ..io.checkpoint import load_checkpoint
from ..runtime.predictions import prediction_format, predictions
from ._common import (
    RESULT_COLUMNS,
    add_query_options,
    add_runtime_options,
    add_search_options,
    format_table,
    load_query,
    print_json,
    run_options,
    search_window,
)

TRACKING_COLUMNS = (
    ("protocol", "protocol"),
    ("k", "k"),
    ("accuracy", "acc %"),
    ("r_at_100p", "R@100P %"),
    ("events", "events/frame"),
    ("window_events", "window frame"),
    ("relocalisations", "re-localisations"),
    ("ms_per_frame", "ms/frame"),
    ("window_ms_per_frame", "window ms/frame"),
)
MODULE_COLUMNS = (
    ("module", "module"),
    ("places", "places"),
    ("n_queries", "queries"),
    ("accuracy", "acc %"),
    ("in_region", "in region %"),
)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("evaluate", help="evaluate a float checkpoint on a query traversal")
    parser.add_argument("checkpoint", help="checkpoint written by train")
    add_query_options(parser)
    parser.add_argument(
        "--baseline",
        action="store_true",
        help="add the no-learning baseline rows: SAD, and cosine nearest neighbour on the same images (the template ceiling)",
    )
    parser.add_argument(
        "--predictions",
        metavar="FILE",
        help="also write every query's decision per strategy and k (query, truth: the ground truth's place ids, "
        "place_id, confidence, correct, note) to FILE: .csv or .jsonl",
    )
    add_search_options(parser)
    add_runtime_options(parser)
    parser.add_argument(
        "--cluster", help=f"run the modules on a Ray cluster, one task per module, CPU workers ({CLUSTER_HELP})"
    )
    parser.set_defaults(handler=run, file_output=lambda args: args.predictions)


def run(args: argparse.Namespace) -> int:
    from ..runtime.evaluation import evaluate_float
    from ..runtime.tracking import tracking_rows

    ckpt = load_checkpoint(args.checkpoint)
    if args.predictions is not None:
        prediction_format(args.predictions)
    cluster = None if args.cluster is None else parse_cluster(args.cluster, threads=args.threads)
    search = search_window(args)
    outputs = () if args.predictions is None else (args.predictions,)  # nor over a file of the data set
    options, _, query = load_query(args, ckpt, outputs, (args.checkpoint,))
    truth = query.truth
    reference_images = None
    if args.baseline:  # the reference frames the network was trained on, loaded on their own (any traversal lengths)
        references = select_places(
            load_selection(ckpt.data, ckpt.reference_traversals, ckpt.config.preprocess, source=args.data),
            ckpt.reference_place_ids,
        )
        reference_images = {t: references.traversal(t) for t in ckpt.reference_traversals}
    result = evaluate_float(
        ckpt,
        query.images,
        query.place_ids,
        args.query,
        options,
        reference_images=reference_images,
        cluster=cluster,
        truth=truth,
        **run_options(args),
    )
    tracking = None
    if search is not None:  # the same frames in stream order, the whole route and the window, one frame at a time
        tracking = tracking_rows(ckpt, query.images, query.place_ids, truth, options, search, threads=args.threads)
    if args.predictions is not None:
        assert result.scored is not None
        written = predictions(result.scored).write(args.predictions)
        print(f"wrote per-query predictions to {written} (scored against the {truth.label})", file=sys.stderr)
    if args.json:
        print_json(
            {
                "config": ckpt.config.to_dict(),
                "checkpoint": str(args.checkpoint),
                "query": args.query,
                "truth": truth.label,
                "threads": args.threads,
                **result.to_dict(),
                **({} if tracking is None else {"tracking": [row.to_dict() for row in tracking]}),
            }
        )
    else:
        print(format_table(result.rows, RESULT_COLUMNS))
        print(f"scored against the {truth.label}")
        if tracking is not None and search is not None:
            print(
                f"\ntracking within {search.places} places (patience {search.patience}"
                f"{'' if search.near is None else f', following within {search.near}'}"
                f"{'' if search.lost_after is None else f', lost after {search.lost_after}'}) beside the whole route, frame by "
                "frame in stream order, accepting at the whole route's precision-1 point on these queries:"
            )
            rows = [
                {
                    **row.to_dict(),
                    "events": f"{row.events_per_frame / 1e6:.2f} M",
                    "window_events": f"{row.window_events_per_frame / 1e6:.2f} M",
                }
                for row in tracking
            ]
            print(format_table(rows, TRACKING_COLUMNS))
        if result.modules is not None:
            print(f"\nper module (W+Prob k=1 over the whole route, {result.silenced} hyperactive neurons silenced):")
            rows = [{**m.to_dict(), "places": f"{m.first_place}-{m.last_place}"} for m in result.modules]
            print(format_table(rows, MODULE_COLUMNS))
        stats = result.spike_stats
        print(
            f"\nthreshold candidates per step: {stats.mean_candidates_per_step:.1f} on average; "
            f"{100 * stats.multi_candidate_step_fraction:.1f} % of steps have more than one",
            file=sys.stderr,
        )
        if result.cost is not None:
            print(result.cost.line(), file=sys.stderr)
        if ckpt.data.get("adaptation"):
            print(f"the network's input is adapted: {ckpt.data['adaptation']}", file=sys.stderr)
    return 0
