"""`vprsnn-export localize`: a trained or deployed network over a stream of frames, one JSON line per frame.

``--frames`` decides causally, one frame at a time; ``--calibrate QUERY`` stores beside the model the operating point
(the confidence threshold that reached ``--precision`` on a labelled query traversal) that ``--frames`` accepts at.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..data.dataset import reference_frame_shape
from ..data.events import EventWindow
from ..data.frames import iter_frames
from ..errors import DataError, InvalidValueError
from ..readout.sequence import SequenceOptions, option_flag
from ..runtime.backends import BACKENDS
from ._common import (
    add_data_options,
    add_runtime_options,
    add_search_options,
    add_sequence_options,
    given_sequence_options,
    positive_int,
    query_data,
    search_window,
    sequence_options,
)

if TYPE_CHECKING:
    from ..runtime.localize import OperatingPoint


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "localize",
        help="localise frame by frame (folder, video or stdin) with a confidence and an operating point",
        description="Run a checkpoint (float network), a fixed-point model (integer simulator) or its exported "
        "ONNX graph over a stream of frames, causally, and print one JSON line per frame. --calibrate QUERY "
        "first picks the confidence threshold for --precision on a labelled query traversal.",
    )
    parser.add_argument("model", help="checkpoint (train) or fixed-point model (quantize)")
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument(
        "--frames",
        metavar="DIR|VIDEO|BAG|EVENTS|-",
        help="a folder of images (name order), a video, a ROS 1 bag (.bag) or ROS 2 bag folder, an event recording "
        "(.npy/.npz/.txt of x, y, t, p), or - (image paths on stdin, one per line)",
    )
    mode.add_argument("--calibrate", metavar="QUERY", help="labelled query traversal: store the operating point")
    parser.add_argument(
        "--backend",
        choices=("auto", *BACKENDS.names()),
        default="auto",
        help="auto (default: float for a checkpoint, integer for a fixed-point model, onnx with --onnx); "
        + "; ".join(f"{b.name}: {b.description}" for b in BACKENDS.values()),
    )
    parser.add_argument(
        "--onnx", metavar="FILE|DEPLOY", help="the ONNX graph exported from MODEL (or its deploy folder)"
    )
    stream = parser.add_argument_group("frame sources (docs/localize.md)")
    stream.add_argument("--topic", metavar="NAME", help="a bag's image topic (needed when it holds several)")
    window = stream.add_mutually_exclusive_group()
    window.add_argument(
        "--event-window-us", type=positive_int, metavar="US", help="events: one frame per US microseconds"
    )
    window.add_argument("--event-count", type=positive_int, metavar="N", help="events: one frame per N events")
    add_sequence_options(parser, stream=True, old_window_option=None, json=False)
    point = parser.add_argument_group("operating point")
    accept = point.add_mutually_exclusive_group()
    accept.add_argument(
        "--precision",
        type=float,
        metavar="P",
        help="--calibrate: the precision to reach (default 1.0); --frames: use the stored point "
        "calibrated for P (default: the stored point when there is one)",
    )
    accept.add_argument("--threshold", type=float, metavar="C", help="--frames: accept at this confidence instead")
    point.add_argument(
        "--operating-point",
        metavar="FILE",
        help="where the operating point is stored (default: MODEL's name + .operating-point.json)",
    )
    add_search_options(parser)
    add_data_options(parser, data_required=False)
    add_runtime_options(parser)
    parser.set_defaults(handler=run, file_output=calibration_output)


def calibration_output(args: argparse.Namespace) -> str | None:
    """The file --calibrate writes (locked for the run like every command's output); None without --calibrate."""
    from ..runtime.localize import operating_point_path

    return None if args.calibrate is None else args.operating_point or str(operating_point_path(args.model))


def run(args: argparse.Namespace) -> int:
    from ..device import resolve_device
    from ..runtime.exporting import load_source, read_export
    from ..runtime.exporting.source import check_against_manifest
    from ..runtime.localize import Localizer, load_operating_point, operating_point_path

    source = load_source(args.model)
    expected = reference_frame_shape(source.network.data, source.network.reference_traversals)
    events = args.event_window_us is not None or args.event_count is not None
    window = EventWindow(window_us=args.event_window_us, count=args.event_count) if events else None
    # a bad source fails before any output; a bag's --topic, an event recording's window
    frames = None if args.frames is None else iter_frames(args.frames, topic=args.topic, events=window, shape=expected)
    point_path = Path(args.operating_point) if args.operating_point else operating_point_path(args.model)
    onnx = None if args.onnx is None else Path(args.onnx)
    if onnx is not None:  # a deploy folder's graph, or a file checked against its folder's manifest
        onnx = read_export(onnx).written("onnx") if onnx.is_dir() else check_against_manifest(onnx)
    device = resolve_device(args.device)
    backend = {"backend": args.backend, "onnx_path": onnx, "device": device, "threads": args.threads}
    if args.calibrate:
        if args.topic is not None or events:
            raise InvalidValueError("--topic, --event-window-us and --event-count are for --frames, not --calibrate")
        if any(v is not None for v in (args.search_window, args.patience, args.follow_within, args.lost_after)):
            raise InvalidValueError(
                "--search-window, --patience, --follow-within and --lost-after are for --frames; --calibrate runs the "
                "whole route"
            )
        return calibrate(args, source, point_path, onnx, backend)
    stored: OperatingPoint | None = None
    if args.threshold is None and (args.precision is not None or point_path.is_file()):
        stored = load_operating_point(point_path, source.sha256)
        if args.precision is not None and stored.precision_target != args.precision:
            raise InvalidValueError(
                f"--precision {args.precision}: the operating point {point_path} was calibrated for "
                f"{stored.precision_target}; run --calibrate with --precision {args.precision}"
            )
    given = given_sequence_options(args)  # over the defaults, or the stored options, which none of them may change
    options = SequenceOptions(**given) if stored is None else stored.options
    for name, value in given.items() if stored is not None else ():
        if value != getattr(options, name):
            raise InvalidValueError(
                f"{option_flag(name)} differs from the operating point's {getattr(options, name)!r} ({point_path}): "
                "its threshold holds for its own options; recalibrate or give --threshold"
            )
    threshold = args.threshold if stored is None else stored.threshold
    if args.threshold is None and stored is None:
        print("note: no operating point (run --calibrate QUERY first): no decision is accepted", file=sys.stderr)
    elif stored is not None and not args.quiet:
        print(f"operating point: {point_path} (threshold {stored.threshold})", file=sys.stderr)
    localizer = Localizer(source.network, options=options, threshold=threshold, search=search_window(args), **backend)
    assert frames is not None
    for decision in localizer.run(sized_frames(frames, expected)):
        sys.stdout.write(json.dumps(decision.to_dict()) + "\n")
        sys.stdout.flush()
    return 0


def sized_frames(
    frames: Iterator[tuple[str, np.ndarray]], expected: tuple[int, int] | None
) -> Iterator[tuple[str, np.ndarray]]:
    """The frames, each checked against the size of the model's reference images (None: not known here)."""
    for name, grey in frames:
        if expected is not None and grey.shape != expected:
            raise DataError(
                f"frame {name!r} is {grey.shape[1]}x{grey.shape[0]} pixels but the model's reference images are "
                f"{expected[1]}x{expected[0]}: a cropped or rescaled stream is refused; give frames of the "
                "reference images' size"
            )
        yield name, grey


def calibrate(args: argparse.Namespace, source, point_path: Path, onnx: Path | None, backend: dict) -> int:
    from ..runtime.localize import Localizer, curve_paths, operating_point, save_curve, save_operating_point
    from ..runtime.report.plots import plot_precision_recall

    if args.threshold is not None:
        raise InvalidValueError("--threshold is for --frames; --calibrate chooses it from --precision")
    network = source.network
    options = sequence_options(args)
    dataset = query_data(args, network, args.calibrate, (point_path, *curve_paths(point_path)), (args.model, onnx))
    localizer = Localizer(network, options=options, **backend)
    truth = dataset.query(args.calibrate, network.reference_traversals, args.match_window).truth
    point, _, curve = operating_point(
        localizer,
        dataset.traversal(args.calibrate),
        dataset.place_ids,
        precision=1.0 if args.precision is None else args.precision,
        truth=truth,
        model_sha256=source.sha256,
        query=args.calibrate,
    )
    chosen = curve.index_for(point.precision_target)
    best = int(np.argmax(curve.precision)) if len(curve.threshold) else None
    print(curve_table(curve, best if chosen is None else chosen, chosen))
    print(other_targets(curve))
    if point.threshold is None:
        reach = (
            f"the best reached is {100 * curve.precision[best]:.1f} % (threshold {float(curve.threshold[best]):.10g}, "
            f"{int(curve.accepted[best])} frames accepted)"
            if best is not None
            else "no query has a decision"
        )
        raise InvalidValueError(
            f"no confidence threshold reaches precision {point.precision_target:g} on the {point.n_queries} "
            f"'{args.calibrate}' queries ({reach}): an operating point that accepts nothing is not written "
            f"({point_path}); give a lower --precision or more calibration queries"
        )
    save_operating_point(point, point_path)
    threshold = f"{point.threshold:.10g}"
    print(
        f"operating point for precision {point.precision_target:g} on {point.n_queries} '{args.calibrate}' queries "
        f"({localizer.backend}, k={localizer.stream.k}): threshold {threshold}; precision {100 * point.precision:.1f} %, "
        f"recall {100 * point.recall:.1f} %; scored against the {truth.label}"
    )
    chosen_point = (point.recall, point.precision, point.threshold)
    title = f"'{point.query}': {point.n_queries} queries, k={localizer.stream.k}"
    plot = plot_precision_recall(curve.recall, curve.precision, point.precision_target, chosen_point, title)
    print(f"wrote {point_path}, " + " and ".join(map(str, save_curve(curve, point, point_path, plot))))
    return 0


def distinct_digits(values: list[float], least: int = 6) -> int:
    """The fewest significant digits (at least ``least``, at most 17) that print distinct values distinctly."""
    return next((d for d in range(least, 17) if len({f"{v:.{d}g}" for v in values}) == len(set(values))), 17)


#: Precision targets whose recall ``--calibrate`` prints beside the one asked for, so the choice is not a guess.
OTHER_TARGETS = (1.0, 0.99, 0.95, 0.9, 0.8, 0.5)


def other_targets(curve) -> str:
    """Each of :data:`OTHER_TARGETS` with the recall and the frames it accepts on the calibration queries."""
    cells = [
        f"{target:g}: unreached"
        if (index := curve.index_for(target)) is None
        else f"{target:g}: recall {100 * curve.recall[index]:.1f} % ({int(curve.accepted[index])} of {curve.n_queries})"
        for target in OTHER_TARGETS
    ]
    return "precision target -> recall (frames accepted): " + "; ".join(cells)


def curve_table(curve, around: int | None, chosen: int | None) -> str:
    """A few points of the calibration curve around point ``around``, the chosen one marked."""
    if around is None:
        return f"precision/recall curve: no decision with a place on the {curve.n_queries} queries"
    rows = curve.rows(around)
    digits = distinct_digits([threshold for threshold, *_ in rows])
    width = max(10, digits + 3)
    lines = [f"{'threshold':>{width}}  {'precision':>9}  {'recall':>7}  {'accepted':>8}"]
    for index, (threshold, precision, recall, accepted) in enumerate(rows, start=max(around - 3, 0)):
        mark = "  <- operating point" if index == chosen else ""
        lines.append(
            f"{threshold:{width}.{digits}g}  {100 * precision:8.1f}%  {100 * recall:6.1f}%  {accepted:8d}{mark}"
        )
    which = "the chosen one" if chosen is not None else "the highest precision"
    return f"precision/recall curve (a few points around {which}):\n" + "\n".join(lines)
