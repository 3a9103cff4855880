"""The tracking protocol beside the global one (issue 43): per k, the localiser over the whole route every frame and
within a search window, scored on a labelled traversal in stream order (``evaluate --search-window``,
``bench/bench_tracking.py``)."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from vprsnn_export.data.truth import Truth
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.io.serial import JsonDataclass
from vprsnn_export.readout.search import SearchWindow
from vprsnn_export.readout.sequence import SequenceOptions

from .localize import Decision, Localizer, calibration_curve, input_spikes, operating_point, predicted_places


@dataclass(frozen=True)
class TrackingRow(JsonDataclass):
    """One protocol's figures on a labelled traversal at one k (:func:`tracking_rows`): the localiser over the
    whole route every frame ("global") or within a search window ("window W"); fractions, events per frame
    (input spikes x neurons run; over every frame, and over the window's frames alone: what a frame costs while
    tracking, whatever the route's length), global frames after the first, and the wall time per frame (over every
    frame, and the mean latency of the window's frames alone; the global protocol: its time per frame)."""

    protocol: str
    k: int
    accuracy: float
    r_at_100p: float
    events_per_frame: float
    relocalisations: int
    ms_per_frame: float
    window_events_per_frame: float  # the global protocol: events_per_frame
    window_ms_per_frame: float  # the global protocol: ms_per_frame


def tracking_rows(
    network: Checkpoint | FixedPointModel,
    images: np.ndarray,
    place_ids: np.ndarray,
    truth: Truth,
    options: SequenceOptions,
    search: SearchWindow,
    *,
    precision: float = 1.0,
    **backend: Any,
) -> list[TrackingRow]:
    """The tracking protocol beside the global one, per k of ``options``, on preprocessed frames (N, inputs) in
    stream order: the global localiser's decisions, the operating point they give at ``precision`` (chosen on these
    same labelled frames, as R@100P is), and the localiser within ``search`` accepting at that point."""

    def row(
        protocol: str, k: int, decisions: list[Decision], events: float, window: float, began: float
    ) -> TrackingRow:
        """One protocol's row from its decisions since ``began`` (R@100P: the recall at precision 1 of their curve;
        the window's frames: those a search window decided, every frame when there are none)."""
        per_frame = 1000 * (time.perf_counter() - began) / max(len(decisions), 1)
        tracked = [d.latency_ms for d in decisions if d.search == "window"]
        curve = calibration_curve(decisions, place_ids, truth)
        index = curve.index_for(1.0)
        return TrackingRow(
            protocol=protocol,
            k=k,
            accuracy=float(np.mean(truth.correct(predicted_places(decisions), np.asarray(place_ids)))),
            r_at_100p=0.0 if index is None else float(curve.recall[index]),
            events_per_frame=float(events),
            relocalisations=max(sum(d.search == "global" for d in decisions) - 1, 0),
            ms_per_frame=per_frame,
            window_events_per_frame=float(window),
            window_ms_per_frame=float(np.mean(tracked)) if tracked else per_frame,
        )

    rows = []
    for k in options.ks:
        at_k = dataclasses.replace(options, ks=(k,))
        whole = Localizer(network, options=at_k, **backend)
        spikes = input_spikes(whole.spikes(np.asarray(images, dtype=np.float32), 0)).sum()
        began = time.perf_counter()
        point, decisions, _ = operating_point(whole, images, place_ids, precision=precision, truth=truth)
        events = float(spikes) * network.calibration.shape[0] / max(len(decisions), 1)
        rows.append(row("global", k, decisions, events, events, began))
        if point.threshold is None:
            raise InvalidValueError(
                f"no confidence reaches precision {precision} at k={k} on these queries: the search window has no "
                "operating point to track with (lower --precision)"
            )
        tracked = Localizer(network, options=at_k, threshold=point.threshold, search=search, **backend)
        began = time.perf_counter()
        decisions = tracked.run_inputs(images)
        events = float(np.mean([d.events or 0 for d in decisions]))
        window = [d.events or 0 for d in decisions if d.search == "window"]
        rows.append(
            row(f"window {search.places}", k, decisions, events, float(np.mean(window)) if window else 0.0, began)
        )
    return rows
