"""The readout as a causal stream: one decision per frame from the recent frames only (the localiser's).

A :class:`ReadoutStream` is made by :meth:`~.scoring.Readout.stream`; it keeps the last k W+Prob rows (and, when
the velocity is tracked, the stream contrast and the recent windows' scores), nothing else.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import numpy as np

from vprsnn_export.errors import InvalidValueError

from .aggregation import aggregate_newest, aggregate_newest_on_support, frame_term, stream_contrast, window_scores
from .sequence import SequenceOptions
from .strategies import SEQUENCE_STRATEGY, decide
from .velocity import VELOCITY_ESTIMATES, causal_estimates


class ReadoutStream:
    """The causal decisions of one readout over a stream of frames (``push``), from frame 0 after ``reset``:
    ``wprob`` turns one frame's counts into its W+Prob row (:meth:`~.scoring.Readout.wprob`), ``options`` say
    how the rows are aggregated."""

    def __init__(self, wprob: Callable[[np.ndarray, slice | None], np.ndarray], options: SequenceOptions) -> None:
        self.wprob, self.options = wprob, options
        self._stream: (
            tuple[deque[np.ndarray], deque[tuple[np.ndarray, np.ndarray]], deque[np.ndarray], deque[np.ndarray]] | None
        ) = None

    @property
    def k(self) -> int:
        """The frames a stream aggregates per decision (the one k of the options)."""
        if len(self.options.ks) != 1:
            raise InvalidValueError(f"a stream decides at one k (--k), got {', '.join(map(str, self.options.ks))}")
        return self.options.ks[0]

    def reset(self) -> None:
        """Forget the stream: the next frame pushed is frame 0."""
        self._stream = None

    def push(self, counts: np.ndarray, places: slice | None = None) -> tuple[int, float, float]:
        """One frame's causal decision from its spike counts (neurons,): (place index or -1, confidence, velocity);
        ``places``: the frame's W+Prob row over those places alone (a search window).

        .. math:: \\hat P_j = \\text{aggregate}(P_{j-k+1..j}, k, v_j), \\quad
                  \\hat l_j = \\arg\\max_l \\hat P_j(l), \\quad c_j = \\max_l \\hat P_j(l)

        at the given velocity, or ``v_j`` tracked causally over the stream contrast Q of the ``memory`` recent
        frames, with the trajectory length T, span S and memory of the estimate's causal form
        (``VelocityEstimator.stream``: "track" 2k, span, memory; "window" k, 1, 0):

        .. math:: e_j(v) = \\max_l A^{(v)}_j(l) \\text{ over the last } T \\text{ frames of } Q, \\quad
                  v_j = \\arg\\max_v \\sum_{i=j-S+1}^{j} e_i(v)

        (the previous windows' e rows kept, at most S - 1; ties to the first candidate).
        """
        options, k = self.options, self.k
        tracking = options.velocity_candidates is not None and k > 1  # else at the given velocity
        causal = VELOCITY_ESTIMATES.get(options.velocity_estimate).stream
        if tracking and causal is None:
            raise InvalidValueError(
                f"--velocity-estimate {options.velocity_estimate} waits for later frames; a stream decides "
                f"causally: choose {' or '.join(causal_estimates())}"
            )
        length, span, memory = causal(k, options) if tracking and causal is not None else (1, 1, 0)
        if self._stream is None:  # the recent W+Prob rows, their terms, stream-contrast rows and window scores
            size = max(k, length, memory)
            self._stream = (deque(maxlen=size), deque(maxlen=k), deque(maxlen=length), deque(maxlen=max(span - 1, 1)))
        recent, terms, contrast, scores = self._stream
        row = self.wprob(counts, places)
        recent.append(row)
        if k > 1:
            terms.append(frame_term(row, options.rule))
        velocity = options.velocity
        if tracking:
            contrast.append(stream_contrast(np.asarray(recent)[-max(memory, 1) :], memory)[-1])
            candidates = np.asarray(options.velocity_candidates)
            last = np.array([len(contrast) - 1])  # the contrast deque holds the last T rows
            newest = window_scores(np.asarray(contrast), length, candidates, options.rule, windows=last)[0]
            total = newest + (np.sum(np.asarray(scores), axis=0) if scores else 0.0)
            velocity = float(candidates[int(np.argmax(total))])
            if span > 1:
                scores.append(newest)
        if k > 1:  # from the terms when the frames are shifted by whole places, else from the rows
            rows, supports = zip(*terms, strict=True)
            final = aggregate_newest_on_support(list(rows), list(supports), velocity, options.rule)
            if final is None:
                final = aggregate_newest(np.asarray(list(recent)[-k:]), k, velocity, options.rule)
        else:
            final = row[None]
        index, confidence = decide(final, SEQUENCE_STRATEGY)
        return int(index[0]), float(confidence[0]), float(velocity)
