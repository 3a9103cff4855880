"""Adaptation from a second, unlabelled traversal (issue 34; docs/research/route-recognition.md §8, §15).

The reference images a_l (every reference place l) and the frames b_q of a second traversal of the same route
(``train --adapt-from``; only the places its ``--adapt-places`` name) are paired, then a statistic of the pairs
becomes part of the model's encoder. Pairing, without labels by default:

    pair(q) = argmax_l sum_{m = 0..k-1} cos(b_{q-m}, a_{l-m})       (k frames along the diagonal, velocity 1;
                                                                     each contiguous stretch of frames on its own)

or by the data set's ground truth (``pairing="truth"``: frame q of place l pairs with a_l). The one mechanism,
the **per-input gain** (``encoder.input_gain``; the encoder applies it, :func:`..data.encoding.adapted_inputs`):

    m_p = (a_p + b_p) / 2,   Var_between,i = Var_p(m_pi),   Var_within,i = mean_p (a_pi - b_pi)^2 / 4
    g_i = sqrt(Var_between,i / (Var_within,i + mean_j Var_within,j))

it keeps the inputs that tell places apart more than they change between the traversals (on Nordland: sky and
horizon kept, ground and track, which snow changes, turned down). It lifted cosine on every quarter of the dev
route and on no half of the LENS example route (§8), so no mechanism is applied unless it is named.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from vprsnn_export.arguments import require_choice
from vprsnn_export.config import Config
from vprsnn_export.data.dataset import Dataset, parse_places
from vprsnn_export.data.truth import GroundTruth
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.readout.baseline import cosine_similarities, diagonal_sums
from vprsnn_export.registry import Registry

#: Frames summed along the diagonal when pairing without labels (research log §8: k = 10 pairs 86-94 % right).
PAIRING_FRAMES = 10


def input_gain(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """g_i = sqrt(Var_between,i / (Var_within,i + mean_j Var_within,j)) of pairs (a_p, b_p), rows of ``a``, ``b``."""
    a, b = a.astype(np.float64), b.astype(np.float64)
    within = np.mean((a - b) ** 2, axis=0) / 4
    between = np.var((a + b) / 2, axis=0)
    floor = within.mean()
    return np.sqrt(between / (within + floor)) if floor > 0 else np.ones(a.shape[1])


def stretches(place_ids: np.ndarray) -> list[np.ndarray]:
    """The positions of ``place_ids`` cut where consecutive ids are not consecutive (each stretch pairs on its own)."""
    return np.split(np.arange(len(place_ids)), np.flatnonzero(np.diff(place_ids) != 1) + 1)


def sequence_pairs(reference: np.ndarray, frames: np.ndarray, frame_ids: np.ndarray, k: int) -> np.ndarray:
    """The reference row matched to each frame without labels: argmax_l of cosine summed over the k most recent
    frames of its stretch along the diagonal (module docstring)."""
    out = np.empty(len(frames), dtype=np.int64)
    for rows in stretches(frame_ids):
        sims = np.clip(cosine_similarities(reference, frames[rows]), 0, None)
        out[rows] = np.argmax(diagonal_sums(sims, k), axis=1)
    return out


@dataclass(frozen=True)
class Mechanism:
    """One adaptation (``--adapt``): ``learn(a, b, cfg)`` -> the config that carries it."""

    name: str
    learn: Callable[[np.ndarray, np.ndarray, Config], Config]
    summary: str


def gained_config(a: np.ndarray, b: np.ndarray, cfg: Config) -> Config:
    gain = input_gain(a, b).astype(np.float32)
    return replace(cfg, encoder=replace(cfg.encoder, input_gain=tuple(float(g) for g in gain)))


MECHANISMS: Registry[Mechanism] = Registry("--adapt")
MECHANISMS.register(Mechanism("gain", gained_config, "per-input gain g_i = sqrt(Var_between / (Var_within + mean))"))


@dataclass(frozen=True)
class Adaptation:
    """What :func:`adapt_config` learnt: the adapted config and a record of it; a checkpoint keeps :attr:`summary`
    (``data.adaptation``)."""

    config: Config
    record: dict

    @property
    def summary(self) -> str:
        """One line: the mechanism, the frames it learnt from and how they were paired."""
        r = self.record
        return (
            f"{r['mechanism']} learnt from {r['frames']} frames of '{r['traversal']}' (places {r['places']}; paired by "
            f"{r['pairing']}, {100 * r['pairs_at_own_place']:.0f} % at their own place id)"
        )


def adapt_config(
    dataset: Dataset,
    references: Sequence[str],
    traversal: str,
    cfg: Config,
    *,
    mechanism: str = "gain",
    places: np.ndarray | None = None,
    pairing: str = "sequence",
    truth: GroundTruth | None = None,
) -> Adaptation:
    """Learn ``mechanism`` from the reference images and the frames of ``traversal`` at ``places`` (default: every
    place of the data set), paired by sequence matching or, with ``pairing="truth"``, by place id.

    With several reference traversals, a place's reference image is their mean. ``traversal`` must not be a
    reference (a traversal used for adaptation is never a reference nor calibrates). ``truth``: the data set's
    ground truth of (reference, ``traversal``) (:func:`~vprsnn_export.data.dataset.scoring_truth`); with
    ``pairing="truth"`` a frame pairs with its first true reference place by it, not by its index.
    """
    learner = MECHANISMS.get(mechanism)
    if traversal in references:
        raise InvalidValueError(f"--adapt-from: {traversal!r} is a reference traversal; name a second traversal")
    if traversal not in dataset.images:
        raise InvalidValueError(f"--adapt-from: no traversal {traversal!r} in the data ({', '.join(dataset.images)})")
    require_choice("pairing", pairing, ("sequence", "truth"))
    ids = np.asarray(dataset.place_ids, dtype=np.int64)
    chosen = ids if places is None else np.asarray(places, dtype=np.int64)
    absent = np.setdiff1d(chosen, ids)
    if len(absent):
        raise InvalidValueError(
            f"--adapt-places: {len(absent)} place(s) are not among the selected places (first: {absent[0]})"
        )
    rows = np.flatnonzero(np.isin(ids, chosen))
    if len(rows) < 2:
        raise InvalidValueError(f"--adapt-places: {len(rows)} of the selected places; adaptation needs 2 or more")
    reference = np.mean([dataset.traversal(name) for name in references], axis=0)
    frames = dataset.traversal(traversal)[rows]
    if pairing == "sequence":
        paired = sequence_pairs(reference, frames, ids[rows], PAIRING_FRAMES)
        how = f"sequence matching, k = {PAIRING_FRAMES}"
    elif truth is None:
        paired, how = rows, "place ids (index-aligned)"
    else:
        paired, how = truth_pairs(truth, ids, ids[rows]), f"ground truth {Path(truth.source).name}"
    record = {
        "mechanism": mechanism,
        "traversal": traversal,
        "frames": int(len(rows)),
        "places": place_ranges(ids[rows]),
        "pairing": how,
        "pairs_at_own_place": round(float(np.mean(paired == rows)), 4),
    }
    return Adaptation(learner.learn(reference[paired], frames, cfg), record)


def truth_pairs(truth: GroundTruth, ids: np.ndarray, frame_ids: np.ndarray) -> np.ndarray:
    """Each frame's first true reference: ``pair(f) = min {l : GT[ids_l, f]}`` (a row of ``ids``); InvalidValueError
    naming the file when the ground truth names no reference place of the selection for a frame."""
    if frame_ids.size and frame_ids.max() >= truth.matrix.shape[1]:
        raise InvalidValueError(f"--adapt-pairing truth: frame {int(frame_ids.max())} is outside {truth.source}")
    paired, known = truth.first_true(ids, frame_ids)
    if not known.all():
        raise InvalidValueError(
            f"--adapt-pairing truth: {truth.source} names no selected reference place for frame {int(frame_ids[~known][0])}"
        )
    return paired


def place_ranges(ids: np.ndarray) -> str:
    """Place ids as START:COUNT ranges joined by commas (the ``--adapt-places`` syntax)."""
    return ",".join(f"{ids[r[0]]}:{len(r)}" for r in stretches(ids))


def parse_place_ranges(spec: str) -> np.ndarray:
    """``"START:COUNT[:STRIDE][,START:COUNT...]"`` (``--adapt-places``) -> the place ids, in order, each once."""
    ids: list[int] = []
    for part in str(spec).split(","):
        try:
            start, count, stride = parse_places(part)
        except InvalidValueError:
            raise InvalidValueError(
                f"--adapt-places {spec!r}: expected START:COUNT[:STRIDE] ranges joined by commas, e.g. 0:600,1200:1200"
            ) from None
        ids.extend(range(start, start + count * stride, stride))
    return np.asarray(list(dict.fromkeys(ids)), dtype=np.int64)
