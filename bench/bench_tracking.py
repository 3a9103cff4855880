"""The search window's tracking protocol beside the global localiser, and a kidnapped robot (issue 43).

    OMP_NUM_THREADS=1 python bench/bench_tracking.py CHECKPOINT [--query winter] [--k 1,5,10]
                                                    [--search-window 300] [--patience 3] [--follow-within P] [--lost-after N]
                                                    [--jump 1000]
                                                    [--frames N] [--backend integer|onnx --onnx FILE]

On the checkpoint's own data (or --data), the query traversal in stream order, per k: the localiser over the whole
route every frame ("global") and within the search window ("window W"; ``runtime.tracking.tracking_rows``), the
window accepting at the global run's operating point at precision 1 on the same frames (as R@100P is chosen):
accuracy and R@100P in %, synaptic events per frame (input spikes x the neurons that ran; over every frame and
over the window's frames alone), global frames after the
first (re-localisations) and wall ms per frame (over every frame, and the window's frames' mean latency alone). Then the kidnapped robot: 100 frames, a jump of --jump places
ahead (modulo the route), 100 frames; per jump, the frames from the jump to the first right decision and to the
first right accepted one, for the window and the global localiser at the largest k (right: the query's truth).
``--frames N``: the table and the operating point on the stream's first N frames only (a long route, whose
every global frame costs the whole route); the kidnappings still jump along the whole traversal. ``--backend integer``
(CHECKPOINT a fixed-point model from ``quantize``) or ``--backend onnx --onnx FILE`` (the graph ``export`` wrote from
it, its ``modules`` input fed the window's modules): the same protocol on a deployment target.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import vprsnn_export as vx
from vprsnn_export.data.dataset import load_selection
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.localize import Localizer, SearchWindow, operating_point, predicted_places
from vprsnn_export.runtime.tracking import tracking_rows
from vprsnn_export.threads import set_threads


def frames_back(decisions, truth, place_ids, after: int) -> tuple[int | None, int | None]:
    """Frames from ``after`` to the first right decision, and to the first right accepted one (None: never)."""
    right = truth.correct(predicted_places(decisions), place_ids)
    first = next((j - after for j in range(after, len(decisions)) if right[j]), None)
    accepted = next((j - after for j in range(after, len(decisions)) if right[j] and decisions[j].accepted), None)
    return first, accepted


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--data", help="the data set (default: the checkpoint's)")
    parser.add_argument("--query", default="winter")
    parser.add_argument("--k", default="1,5,10")
    parser.add_argument("--search-window", type=int, default=300)
    parser.add_argument("--patience", type=int, default=3)
    parser.add_argument(
        "--follow-within", type=int, help="an unaccepted decision this near the expected place is no miss"
    )
    parser.add_argument("--lost-after", type=int, help="window frames without an accepted decision before a global one")
    parser.add_argument("--jump", type=int, default=1000, help="places the kidnapped robot jumps ahead")
    parser.add_argument("--jumps", type=int, default=5, help="kidnappings, at evenly spaced frames")
    parser.add_argument("--frames", type=int, help="the table on the first N frames (default: all)")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--backend", default="float", choices=("float", "integer", "onnx"))
    parser.add_argument("--onnx", help="with --backend onnx: the graph exported from the fixed-point model")
    args = parser.parse_args()
    set_threads(args.threads)
    ckpt = (vx.load_checkpoint if args.backend == "float" else vx.load_fixed_point)(args.checkpoint)
    backend = {"backend": args.backend, "onnx_path": args.onnx, "threads": args.threads}
    dataset = load_selection(ckpt.data, [args.query], ckpt.config.preprocess, source=args.data)
    query = dataset.query(args.query, ckpt.reference_traversals)
    ks = tuple(int(k) for k in args.k.split(","))
    search = SearchWindow(args.search_window, args.patience, args.follow_within, args.lost_after)
    n = len(query.place_ids)
    first = slice(0, args.frames)
    print(
        f"load average {os.getloadavg()[0]:.1f}; {args.checkpoint}: {ckpt.calibration.shape[0]} neurons, "
        f"{ckpt.calibration.shape[1]} places; query {args.query} ({n} frames, the table on {len(query.place_ids[first])}); window {search.places} places, "
        f"patience {search.patience}, follow within {search.near}, lost after {search.lost_after}; backend {args.backend}; {args.threads} thread(s)"
    )
    began = time.perf_counter()
    rows = tracking_rows(
        ckpt, query.images[first], query.place_ids[first], query.truth, SequenceOptions(ks=ks), search, **backend
    )
    header = (
        f"{'protocol':<12} {'k':>3} {'acc %':>6} {'R@100P %':>9} {'events/frame M':>15} {'window frame M':>15} "
        f"{'reloc':>6} {'ms/frame':>9} {'window ms':>10}"
    )
    print(header + "\n" + "-" * len(header))
    for r in rows:
        print(
            f"{r.protocol:<12} {r.k:>3} {100 * r.accuracy:>6.1f} {100 * r.r_at_100p:>9.1f} {r.events_per_frame / 1e6:>15.2f} "
            f"{r.window_events_per_frame / 1e6:>15.2f} {r.relocalisations:>6} {r.ms_per_frame:>9.2f} {r.window_ms_per_frame:>10.2f}"
        )
    print(f"({time.perf_counter() - began:.0f} s)")
    options = SequenceOptions(ks=(ks[-1],))
    whole = Localizer(ckpt, options=options, **backend)
    point, _, _ = operating_point(whole, query.images[first], query.place_ids[first], truth=query.truth)
    tracked = Localizer(ckpt, options=options, threshold=point.threshold, search=search, **backend)
    whole = Localizer(ckpt, options=options, threshold=point.threshold, **backend)
    print(f"\nkidnapped at k={ks[-1]}: 100 frames, a jump of {args.jump} places, 100 frames; frames to the first right")
    print("decision / the first right accepted one (window | global):")
    for start in np.linspace(100, n - 100, args.jumps, dtype=int):
        to = (start + args.jump) % (n - 100)
        stream = np.r_[np.arange(start - 100, start), np.arange(to, to + 100)]
        images, ids = query.images[stream], query.place_ids[stream]
        window = frames_back(tracked.run_inputs(images), query.truth, ids, 100)
        every = frames_back(whole.run_inputs(images), query.truth, ids, 100)
        print(f"  frame {start} -> place index {to}: {window[0]} / {window[1]} | {every[0]} / {every[1]}")


if __name__ == "__main__":
    main()
