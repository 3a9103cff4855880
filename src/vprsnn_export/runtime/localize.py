"""Online localisation: one frame at a time, causal, on any backend (`vprsnn-export localize`).

Each frame ``j`` (a greyscale image of any size) is resized and preprocessed like the training
data, encoded under the presentation key ``(seed, "localize", stream, j)`` and presented to the
network alone (state isolation, as in evaluation). Its spike counts give the W+Prob distribution
``P_j`` over the reference places (an ensemble's with its region regularisation), and
:meth:`vprsnn_export.readout.scoring.Readout.push` decides: the same readout as a batch's, with its
query-independent half computed once. The decision aggregates the ``k`` most
recent frames only (:func:`vprsnn_export.readout.aggregation.aggregate`):

.. math:: \\hat P_j = \\text{aggregate}(P_{j-k+1..j}, k, v_j), \\quad
          \\hat l_j = \\arg\\max_l \\hat P_j(l), \\quad c_j = \\max_l \\hat P_j(l),
          \\quad \\text{accepted}_j = c_j \\ge \\theta

at a given velocity ``v``, or with ``velocity_candidates`` (and a causal ``velocity_estimate``) the tracker of
:func:`vprsnn_export.readout.aggregation.track_velocity`: ``v_j`` maximises the window scores of
the ``span`` most recent windows of ``2k`` frames on the stream contrast of the ``memory`` most
recent frames. **Lag**: the decision for frame ``j`` is given as soon as frame ``j`` arrives
(0 frames of delay; the fixed-lag "smooth" estimate of ``evaluate`` waits ``2k - 1`` frames and is
not offered here); the velocity it uses is fitted to frames ``j - span - 2k + 2 .. j``, so it
follows a change of speed with a delay of about ``span`` frames.

The operating point ``theta`` comes from a labelled calibration run (:func:`operating_point`):
with ``precision = 1.0`` the lowest confidence threshold at which every accepted calibration
decision was right. It is stored beside the model (:func:`save_operating_point`).

Backends: the registered ones (:data:`vprsnn_export.runtime.backends.BACKENDS`), e.g. ``float`` (a checkpoint),
``integer`` (the integer simulator) and ``onnx`` (the graph exported from the fixed-point model), each run with
state isolation. Each returns the spike counts and the readout above runs on them, so the integer simulator and
the ONNX graph, which agree count for count, give the same decisions.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from vprsnn_export.arguments import real_number, require_type
from vprsnn_export.config import Config
from vprsnn_export.data.encoding import encode, presentation_seed
from vprsnn_export.data.preprocess import normalise_resized, resize_image
from vprsnn_export.data.truth import EXACT, Truth
from vprsnn_export.errors import InvalidValueError, ModelFileError
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.io.fileio import atomic_write_bytes, atomic_write_text, is_readable_file, parse_json
from vprsnn_export.io.serial import JsonDataclass, json_options
from vprsnn_export.readout.early import early_run
from vprsnn_export.readout.metrics import operating_points
from vprsnn_export.readout.scoring import Readout
from vprsnn_export.readout.search import SearchWindow
from vprsnn_export.readout.sequence import SequenceOptions

from .backends import open_backend

if TYPE_CHECKING:
    from vprsnn_export.network.runs import Backend

STREAM = "localize"
PARTS_KEPT = 16  # the search window's networks kept open (the most recent windows' modules)
OPERATING_POINT_FORMAT = "vprsnn-operating-point/1"
OPERATING_POINT_SUFFIX = ".operating-point.json"
CURVE_FORMAT = "vprsnn-precision-recall/1"
CURVE_POINT = ("threshold", "precision", "recall", "accepted")  # a curve point's keys in the curve's JSON


@dataclass(frozen=True)
class Decision(JsonDataclass):
    """One frame's answer: the place (None: no match), its confidence, whether it is accepted, the
    velocity used and the latency from the decoded frame to the decision. ``reason`` (None: decided) says
    why a frame that carries no place has no decision (:func:`no_place_reasons`)."""

    frame: int
    name: str
    place_id: int | None
    confidence: float
    accepted: bool
    velocity: float
    latency_ms: float
    reason: str | None = field(default=None, metadata=json_options(omit="none"))
    # with a search window: synaptic events of the frame (input spikes x neurons run), "window" or "global", and the
    # modules run [first, last) (on a Loihi-style deployment, the populations whose cores are powered for the frame)
    events: int | None = field(default=None, metadata=json_options(omit="none"))
    search: str | None = field(default=None, metadata=json_options(omit="none"))
    modules: tuple[int, int] | None = field(default=None, metadata=json_options(omit="none"))


#: Why a frame carries no place, in the order they are checked (:func:`no_place_reasons`).
NO_PLACE = ("no contrast", "no input spike", "no output spike")


def input_spikes(spikes: torch.Tensor) -> np.ndarray:
    """Per presentation, its input spikes ``sum_{t,i} s_{ti}`` (N,) int64."""
    return spikes.reshape(len(spikes), -1).cpu().numpy().sum(axis=1, dtype=np.int64)


def no_place_reasons(flat: np.ndarray, inputs: np.ndarray, counts: np.ndarray) -> list[str | None]:
    """Per frame, why it carries no place (None: it does): ``flat``, its resized image is uniform (a 1x1 or
    flat grey frame, ``max R = min R``: what the input channels then show is their own border, not the
    scene), its spike train holds no spike (``inputs``: :func:`input_spikes` = 0) or the network answered with none
    (``sum_n c_n = 0``). Such a frame is no evidence of any place, so it gets no decision, whatever the
    recent frames say."""
    silent_input = np.asarray(inputs) == 0
    silent_output = np.asarray(counts).reshape(len(counts), -1).sum(axis=1) == 0
    reason = np.select([np.asarray(flat, dtype=bool), silent_input, silent_output], list(NO_PLACE), default="")
    return [str(r) or None for r in reason]


@dataclass(frozen=True)
class OperatingPoint:
    """A confidence threshold chosen on labelled calibration queries (``threshold`` None: none qualified,
    nothing is accepted)."""

    threshold: float | None
    precision_target: float
    precision: float  # achieved on the calibration queries (1.0 when nothing is accepted)
    recall: float  # accepted and correct / all calibration queries
    n_queries: int
    options: SequenceOptions
    model_sha256: str
    backend: str
    query: str
    match_window: int
    ground_truth: str = ""  # the ground-truth file the calibration queries were scored against ("" : by index)

    def accepts(self, confidence: float, place_id: int | None) -> bool:
        return self.threshold is not None and place_id is not None and confidence >= self.threshold

    def to_dict(self) -> dict[str, Any]:
        return {"format": OPERATING_POINT_FORMAT, **asdict(self)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> OperatingPoint:
        fields = {k: v for k, v in data.items() if k != "format"}
        return cls(**{**fields, "options": SequenceOptions.from_dict(fields["options"])})


def frame_counts(runner: Any, spikes: torch.Tensor, calibration: np.ndarray, config: Config) -> np.ndarray:
    """The spike counts a frame is decided on: the whole presentation's, or with ``config.early`` on, the counts
    up to the step the early rule stops at (:func:`~vprsnn_export.readout.early.early_run`), as in evaluate."""
    early = early_run(runner.run, spikes, calibration, config, isolated=True)
    return runner.run(spikes).counts.cpu().numpy() if early is None else np.asarray(early.counts)


def network_part(network: Checkpoint | FixedPointModel, neurons: slice) -> Checkpoint | FixedPointModel:
    """The network of some consecutive modules' neurons alone (their weights, thresholds and S^R rows); the weight
    columns copied contiguous once (the kernels would copy a strided view at every frame)."""
    if isinstance(network, Checkpoint):
        return dataclasses.replace(
            network,
            weights=np.ascontiguousarray(network.weights[:, neurons]),
            thresholds=network.thresholds[neurons],
            calibration=network.calibration[neurons],
        )
    return dataclasses.replace(
        network,
        weight_mantissa=np.ascontiguousarray(network.weight_mantissa[:, neurons]),
        scale_multiplier=network.scale_multiplier[neurons],
        threshold=network.threshold[neurons],
        calibration=network.calibration[neurons],
        float_calibration=network.float_calibration[neurons],
    )


class Localizer:
    """A trained or deployed network answering one frame at a time (``push``), causally.

    ``network``: a float checkpoint (backend ``float``) or a fixed-point model (``integer``, or
    ``onnx`` with ``onnx_path``, the graph exported from that model). ``threshold``: accept a
    decision when its confidence reaches it (None: accept none), e.g. an :class:`OperatingPoint`'s.
    """

    def __init__(
        self,
        network: Checkpoint | FixedPointModel,
        *,
        backend: str = "auto",
        options: SequenceOptions | None = None,
        threshold: float | None = None,
        onnx_path: str | Path | None = None,
        device: torch.device | None = None,
        threads: int | None = None,
        search: SearchWindow | None = None,
    ) -> None:
        if not isinstance(network, Checkpoint | FixedPointModel):
            raise InvalidValueError(
                f"network must be a Checkpoint (vx.load_checkpoint) or a FixedPointModel (vx.load_fixed_point), "
                f"got {type(network).__name__}"
            )
        if threshold is not None and not 0.0 <= real_number("threshold", threshold) <= 1.0:
            raise InvalidValueError(f"threshold must be a confidence in [0, 1] or None, got {threshold!r:.40}")
        self.network = network
        self.readout = Readout.of(network.calibration, network.config, options)  # it checks the options
        self.options = self.readout.options
        self.threshold = threshold
        self.config: Config = network.config
        isolated = dataclasses.replace(network, config=network.config.replace(**{"network.state_isolation": True}))
        self.backend, runner = open_backend(isolated, backend, onnx_path, device, threads)
        self._counts = lambda spikes: frame_counts(runner, spikes, network.calibration, isolated.config)
        self.search = search
        if search is not None:
            require_type("search", search, SearchWindow)
            if self.readout.modules is None or len(self.readout.modules.regions) < 2:
                raise InvalidValueError("--search-window needs an ensemble of modules (train.module_size > 0)")
            self._regions = self.readout.modules.regions
            # an ONNX graph's one session runs every window (targets.onnx_session.SessionBackend's modules input)
            graph: Any = runner if self.backend == "onnx" else None
            if graph is not None and "modules" not in {i.name for i in graph.session.get_overridable_initializers()}:
                raise InvalidValueError(
                    "--search-window needs a graph with the modules input: export it again with this version"
                )
            if threshold is None:
                raise InvalidValueError(
                    "--search-window needs an operating point: it tracks the last accepted place "
                    "(run `localize MODEL --calibrate QUERY` first)"
                )

            @functools.lru_cache(PARTS_KEPT)
            def window_counts(start: int, stop: int) -> Callable[[torch.Tensor], np.ndarray]:
                """The counts of neurons ``start:stop`` (some consecutive modules) alone, their network opened once (an
                ONNX graph runs them on its one session: its ``modules`` input)."""
                part = network_part(isolated, slice(start, stop))
                if graph is not None:
                    group = self.config.network.n_neurons
                    run: Backend = dataclasses.replace(graph, modules=(start // group, stop // group))
                else:
                    run = open_backend(part, self.backend, None, device, threads)[1]
                return lambda s: frame_counts(run, s, part.calibration, part.config)

            self._window_counts = window_counts
        self.stream = self.readout.stream()
        self.stream.push(np.zeros(network.calibration.shape[0]))  # checks the options before any frame
        self._counts(torch.zeros((1, self.config.encoder.timesteps, self.config.network.n_inputs), dtype=torch.uint8))
        self.reset()  # the silent presentation above compiled the kernels: the first frame's latency is its own

    def reset(self) -> None:
        """Forget the stream: the next frame is frame 0 (and global, with a search window)."""
        self.frame = 0
        self.stream.reset()
        self.centre: float | None = None  # the search window's centre, a reference place index (None: global)
        self.misses = 0  # frames in a row without an accepted decision (SearchWindow.follow)
        self.waited = 0  # window frames in a row without an accepted decision, followed ones included

    def _frame_counts(
        self, spikes: torch.Tensor
    ) -> tuple[np.ndarray, slice | None, str | None, tuple[int, int] | None]:
        """The frames' counts over every neuron, the places they are decided among (None: all), the search (None: no
        search window) and the modules run (None: no search window): the whole network, or (one frame) the window's
        modules alone."""
        group = self.config.network.n_neurons
        if self.search is None:
            return self._counts(spikes), None, None, None
        if self.centre is None:
            return self._counts(spikes), None, "global", (0, len(self._regions))
        first, last = self.search.modules(self.centre, self._regions)
        counts = np.zeros((len(spikes), self.network.calibration.shape[0]), dtype=np.int64)
        counts[:, first * group : last * group] = self._window_counts(first * group, last * group)(spikes)
        places = slice(int(self._regions[first, 0]), int(self._regions[last - 1, 1]))
        return counts, places, "window", (first, last)

    def preprocess(self, grey: np.ndarray) -> np.ndarray:
        """A greyscale uint8 frame (any size) -> the network's input vector, shape (1, inputs)."""
        return normalise_resized(self._resized(np.asarray(grey))[None], self.config.preprocess)

    def _resized(self, grey: np.ndarray) -> np.ndarray:
        if grey.ndim != 2 or grey.size == 0 or grey.dtype.kind not in "uif":
            raise InvalidValueError(
                f"a frame must be a non-empty 2-D greyscale array (height, width) of numbers, got shape {grey.shape} "
                f"{grey.dtype}"
            )
        if grey.dtype.kind == "f" and not np.isfinite(grey).all():
            raise InvalidValueError("a frame holds NaN or infinite values")
        return resize_image(grey, self.config.preprocess.image_size)

    def spikes(self, images: np.ndarray, first_frame: int) -> torch.Tensor:
        """Spike trains of preprocessed frames numbered from ``first_frame`` (N, T, inputs) uint8."""
        seeds = [presentation_seed(self.config.seed, STREAM, STREAM, first_frame + i) for i in range(len(images))]
        return encode(images, seeds, self.config.encoder)

    def counts(self, images: np.ndarray, first_frame: int) -> np.ndarray:
        """Spike counts (N, neurons) of preprocessed frames numbered from ``first_frame`` (one network run)."""
        return self._counts(self.spikes(images, first_frame))

    def push(self, grey: np.ndarray, name: str = "") -> Decision:
        """Present one frame and decide: :class:`Decision` (its latency covers preprocessing to decision)."""
        began = time.perf_counter()
        resized = self._resized(np.asarray(grey))
        spikes = self.spikes(normalise_resized(resized[None], self.config.preprocess), self.frame)
        return self._present(spikes, np.ptp(resized)[None] == 0, [name], began)[0]

    def run(self, frames: Iterable[tuple[str, np.ndarray]]) -> Iterator[Decision]:
        """``push`` over ``(name, grey)`` frames as they come."""
        return (self.push(grey, name) for name, grey in frames)

    def run_batch(self, grey_frames: np.ndarray | list[np.ndarray], names: list[str] | None = None) -> list[Decision]:
        """The decisions ``push`` would give on these greyscale frames (in order, from frame 0), with the
        network run once over all of them; ``latency_ms`` is the per-frame share."""
        resized = np.stack([self._resized(np.asarray(g)) for g in grey_frames])
        flat = np.ptp(resized.reshape(len(resized), -1), axis=1) == 0
        return self.run_inputs(normalise_resized(resized, self.config.preprocess), names, flat)

    def run_inputs(
        self, inputs: np.ndarray, names: list[str] | None = None, flat: np.ndarray | None = None
    ) -> list[Decision]:
        """:meth:`run_batch` on preprocessed frames (N, inputs), e.g. a :class:`~vprsnn_export.data.dataset.Dataset`'s.

        The integer simulator and the ONNX graph give exactly ``push``'s decisions. The float network
        sums its input currents in this machine's BLAS order, which depends on the batch size, so a
        batched float run may differ from ``push`` in the last bit of a current (rarely a spike). ``flat``: per
        frame, whether its resized image was uniform (:func:`no_place_reasons`; None: none was).
        """
        self.reset()
        began = time.perf_counter()
        spikes = self.spikes(np.asarray(inputs, dtype=np.float32), 0)
        flat = np.zeros(len(spikes), bool) if flat is None else flat
        labels = names if names is not None else [str(i) for i in range(len(spikes))]
        if self.search is None:
            return self._present(spikes, flat, labels, began)
        # each frame's window follows the decisions before it: one frame at a time
        frames = (slice(j, j + 1) for j in range(len(spikes)))
        return [self._present(spikes[j], flat[j], labels[j], time.perf_counter())[0] for j in frames]

    def _present(self, spikes: torch.Tensor, flat: np.ndarray, names: list[str], began: float) -> list[Decision]:
        """Frames' spike trains (N, T, inputs) run at once from ``began`` (with a search window: one frame) and
        decided in order, each latency with its share of the run (``flat``: :func:`no_place_reasons`).

        The readout's causal decision on each frame's counts; none (place None, not accepted) with its reason for
        a frame that carries no place (the frame still enters the readout's window, as in a batch). With a search
        window the decision moves it (:class:`SearchWindow`)."""
        inputs = input_spikes(spikes)
        counts, places, search, modules = self._frame_counts(spikes)
        run = None if modules is None else (modules[1] - modules[0]) * self.config.network.n_neurons
        share = (time.perf_counter() - began) / max(len(counts), 1)
        decisions = []
        for row, name, reason in zip(counts, names, no_place_reasons(flat, inputs, counts), strict=True):
            start = time.perf_counter() - share
            index, conf, velocity = self.stream.push(row, places)
            place = None if index < 0 or reason is not None else int(self.network.reference_place_ids[index])
            accepted = self.threshold is not None and place is not None and conf >= self.threshold
            if self.search is not None:
                found = index if place is not None else None
                tracking = self.centre is not None
                self.centre, self.misses, self.waited = self.search.follow(
                    self.centre, self.misses, found, accepted, velocity, self.waited
                )
                if tracking and self.search.lost(self.waited):  # the recent frames are the lost window's: forgotten
                    self.stream.reset()
            decision = Decision(
                frame=self.frame,
                name=name,
                place_id=place,
                confidence=0.0 if place is None else conf,
                accepted=accepted,
                velocity=float(velocity),
                latency_ms=1000 * (time.perf_counter() - start),
                reason=reason,
                events=None if run is None else int(inputs.sum()) * run,
                search=search,
                modules=modules,
            )
            decisions.append(decision)
            self.frame += 1
        return decisions


@dataclass(frozen=True, eq=False)
class PrecisionRecallCurve:
    """The calibration decisions' precision/recall curve, one point per distinct confidence ``theta``
    (descending; only decisions with a place, confidence > 0, are ever accepted):

    .. math:: A(\\theta) = |\\{j : c_j \\ge \\theta\\}|, \\quad
              \\text{precision}(\\theta) = \\frac{|\\{j : c_j \\ge \\theta, \\text{correct}_j\\}|}{A(\\theta)}, \\quad
              \\text{recall}(\\theta) = \\frac{|\\{j : c_j \\ge \\theta, \\text{correct}_j\\}|}{N}

    over all ``N`` calibration queries (a query without a decision counts against the recall)."""

    threshold: np.ndarray
    precision: np.ndarray
    recall: np.ndarray
    accepted: np.ndarray
    n_queries: int

    @classmethod
    def of(cls, confidence: np.ndarray, correct: np.ndarray) -> PrecisionRecallCurve:
        c = np.asarray(confidence, dtype=np.float64)
        keep = c > 0
        if not keep.any():
            return cls(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, np.int64), len(keep))
        hits, accepted, threshold, _ = operating_points(np.asarray(correct, dtype=bool)[keep], c[keep])
        return cls(threshold, hits / accepted, hits / len(keep), accepted, len(keep))

    def index_for(self, precision: float) -> int | None:
        """The point of the lowest threshold whose precision reaches ``precision`` (None: no point does)."""
        reached = np.flatnonzero(self.precision >= precision - 1e-12)
        return int(reached[-1]) if reached.size else None

    def rows(self, around: int, n: int = 3) -> list[tuple[float, float, float, int]]:
        """(threshold, precision, recall, accepted) of the ``n`` points either side of point ``around``."""
        lo, hi = max(around - n, 0), min(around + n + 1, len(self.threshold))
        columns = (getattr(self, name)[lo:hi] for name in CURVE_POINT)
        return [(float(t), float(p), float(r), int(a)) for t, p, r, a in zip(*columns, strict=True)]

    def to_dict(self) -> dict[str, Any]:
        points = [dict(zip(CURVE_POINT, row, strict=True)) for row in self.rows(0, len(self.threshold))]
        return {"n_queries": self.n_queries, "points": points}


def precision_threshold(confidence: np.ndarray, correct: np.ndarray, precision: float) -> float | None:
    """The lowest confidence threshold whose accepted decisions reach ``precision``:

    .. math:: \\theta = \\min \\{ \\theta' : \\text{precision}(\\theta') \\ge p \\}

    on :class:`PrecisionRecallCurve`; None when no threshold qualifies.
    """
    curve = PrecisionRecallCurve.of(confidence, correct)
    index = curve.index_for(precision)
    return None if index is None else float(curve.threshold[index])


def operating_point(
    localizer: Localizer,
    inputs: np.ndarray,
    place_ids: np.ndarray,
    *,
    precision: float = 1.0,
    truth: Truth = EXACT,
    model_sha256: str = "",
    query: str = "",
) -> tuple[OperatingPoint, list[Decision], PrecisionRecallCurve]:
    """Run the localiser over labelled preprocessed frames (N, inputs) in stream order (a query traversal)
    and choose the threshold for ``precision``; ``truth`` says which decisions are right (a match window, or the
    data set's ground truth). Returns the point, the decisions and the curve it was chosen from
    (:func:`calibration_curve`)."""
    if not 0 < precision <= 1:
        raise InvalidValueError(f"--precision must lie in (0, 1], got {precision}")
    decisions = localizer.run_inputs(inputs)
    curve = calibration_curve(decisions, place_ids, truth)
    index = curve.index_for(precision)
    point = OperatingPoint(
        threshold=None if index is None else float(curve.threshold[index]),
        precision_target=float(precision),
        precision=1.0 if index is None else float(curve.precision[index]),
        recall=0.0 if index is None else float(curve.recall[index]),
        n_queries=len(decisions),
        options=localizer.options,
        model_sha256=model_sha256,
        backend=localizer.backend,
        query=query,
        match_window=truth.match_window,
        ground_truth=truth.source,
    )
    return point, decisions, curve


def calibration_curve(decisions: list[Decision], place_ids: np.ndarray, truth: Truth = EXACT) -> PrecisionRecallCurve:
    """The precision/recall curve of labelled decisions (:class:`PrecisionRecallCurve`); right as in
    :func:`operating_point`."""
    correct = truth.correct(predicted_places(decisions), np.asarray(place_ids))
    return PrecisionRecallCurve.of(np.asarray([d.confidence for d in decisions]), correct)  # no place: confidence 0


def predicted_places(decisions: list[Decision]) -> np.ma.MaskedArray:
    """The decisions' place ids, masked where a frame has none."""
    placed = np.asarray([d.place_id is not None for d in decisions], dtype=bool)
    return np.ma.MaskedArray([d.place_id or 0 for d in decisions], mask=~placed, dtype=np.int64)


def _is_real(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def operating_point_problem(point: OperatingPoint) -> str | None:
    """What makes a stored operating point unusable (None: nothing): a threshold that is not a finite confidence
    > 0 (-1 or 0 would accept every frame, NaN none), a precision target outside (0, 1], an achieved precision
    or recall outside [0, 1], a query count or match window that is not a non-negative integer."""
    if point.threshold is not None and not (_is_real(point.threshold) and point.threshold > 0):
        return f"threshold {point.threshold!r} is not a confidence > 0"
    if not (_is_real(point.precision_target) and 0 < point.precision_target <= 1):
        return f"precision_target {point.precision_target!r} is not in (0, 1]"
    for name in ("precision", "recall"):
        value = getattr(point, name)
        if not (_is_real(value) and 0 <= value <= 1):
            return f"{name} {value!r} is not in [0, 1]"
    for name in ("n_queries", "match_window"):
        value = getattr(point, name)
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            return f"{name} {value!r} is not a non-negative integer"
    for name in ("model_sha256", "backend", "query", "ground_truth"):
        if not isinstance(getattr(point, name), str):
            return f"{name} is not a string"
    return None


def operating_point_path(model_path: str | Path) -> Path:
    """Where a model's operating point is stored: beside it, ``<model stem>.operating-point.json``."""
    path = Path(model_path)
    return path.with_name(path.stem + OPERATING_POINT_SUFFIX)


def save_operating_point(point: OperatingPoint, path: str | Path) -> Path:
    return atomic_write_text(path, json.dumps(point.to_dict(), indent=2) + "\n")


def curve_paths(point_path: str | Path) -> tuple[Path, Path]:
    """Where the curve an operating point was chosen from is written: beside it, ``<point>.curve.json`` and
    ``<point>.curve.png`` (``net.operating-point.json`` -> ``net.operating-point.curve.json``)."""
    base = Path(point_path).with_suffix("")
    return base.with_name(base.name + ".curve.json"), base.with_name(base.name + ".curve.png")


def save_curve(
    curve: PrecisionRecallCurve, point: OperatingPoint, point_path: str | Path, png: bytes
) -> tuple[Path, Path]:
    """The curve as JSON (every point, the chosen threshold and target) and its plot ``png``, beside the point."""
    data = {"format": CURVE_FORMAT, "threshold": point.threshold, "precision_target": point.precision_target}
    json_path, png_path = curve_paths(point_path)
    atomic_write_text(json_path, json.dumps({**data, **curve.to_dict()}, indent=1) + "\n")
    return json_path, atomic_write_bytes(png_path, png)


def load_operating_point(path: str | Path, model_sha256: str | None = None) -> OperatingPoint:
    """Read an operating point; ModelFileError when it is missing, malformed or made for another model."""
    path = Path(path)
    if not is_readable_file(path):
        raise ModelFileError("no operating point here: run `localize MODEL --calibrate QUERY` first", path)
    try:
        data = parse_json(path.read_bytes(), "operating point")
        if data.get("format") != OPERATING_POINT_FORMAT:
            raise ModelFileError(f"not an operating point (format {data.get('format')!r})", path)
        point = OperatingPoint.from_dict(data)
    # ValueError: InvalidValueError of a JSON beyond its limits or of malformed options
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, TypeError, KeyError, AttributeError, ValueError) as exc:
        raise ModelFileError(f"corrupt operating point ({exc})", path) from None
    if problem := operating_point_problem(point):
        raise ModelFileError(f"tampered or corrupt operating point: {problem}", path)
    if model_sha256 is not None and point.model_sha256 != model_sha256:
        raise ModelFileError("this operating point was calibrated on another model file (sha256 differs)", path)
    return point
