"""The no-learning baselines: storing the reference images and matching queries against them.

The same preprocessed (e.g. DoG ON/OFF, flattened) images that the network sees are compared with
every reference image, two ways:

* **cosine nearest neighbour** (:func:`cosine_similarities`): the template ceiling. With hard WTA and
  L2-normalised weights the network is a Poisson-noisy cosine matcher over learnt templates, so this
  is the baseline the network must beat to be worth learning (docs/research/route-recognition.md).
* **SAD** (:func:`sad_distances`): sum of absolute differences, the paper's reference.

Both are read out as **nearest neighbour** (:func:`nearest_neighbour`): the best place, the margin
between the best and the second-best score as the confidence, and sequences of k frames as the
scores summed along the velocity-shifted diagonal (:func:`diagonal_sums`). SAD can also be read out
like W+Prob (:func:`sad_distribution`), the protocol of the earlier route pages.
"""

from __future__ import annotations

import numpy as np

from vprsnn_export.arguments import real_array
from vprsnn_export.errors import InvalidValueError

# the aggregation's bound on one chunk's working array: diagonal_sums' (chunk, k, places) windows, SAD's differences
from .aggregation import _MAX_ELEMENTS, count_at_least, shift_window
from .assignment import NO_MATCH, finite_array, finite_matrix, wprob_distribution


def _images(reference: np.ndarray, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The reference and query images as finite float64 (n_images, n_pixels) arrays of the same width."""
    arrays = []
    for name, a in (("reference", reference), ("queries", queries)):
        arr = real_array(name, a)
        if arr.ndim != 2:
            raise InvalidValueError(f"{name} must be 2-D (n_images, n_pixels), got shape {arr.shape}")
        arrays.append(finite_array(name, arr))
    ref, qry = arrays
    if ref.shape[1] != qry.shape[1]:
        raise InvalidValueError(f"reference images have {ref.shape[1]} pixels but queries have {qry.shape[1]}")
    return ref, qry


def sad_distances(reference: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Sum of absolute differences, shape ``(n_queries, n_places)``.

    .. math:: D_{ql} = \\sum_{p=1}^{D} |Q_{qp} - R_{lp}|

    ``reference``: ``(n_places, D)``, ``queries``: ``(n_queries, D)``, both the flattened preprocessed images.
    Computed over chunks of queries so that the ``(chunk, n_places, D)`` difference array stays below ~4M elements.
    """
    ref, qry = _images(reference, queries)
    out = np.empty((qry.shape[0], ref.shape[0]), dtype=np.float64)
    chunk = max(1, _MAX_ELEMENTS // max(1, ref.size))
    for start in range(0, qry.shape[0], chunk):
        out[start : start + chunk] = np.abs(qry[start : start + chunk, None, :] - ref[None, :, :]).sum(axis=2)
    return out


def sad_distribution(distances: np.ndarray) -> np.ndarray:
    """Per-query distribution over places from SAD distances, shape ``(n_queries, n_places)``.

    The similarity is the negated distance, ``s_l = -D_l``; it is min-max normalised and L1-normalised exactly like
    W+Prob (eq. 12-13):

    .. math:: P(l \\mid Q) = \\frac{(\\max_m D_m - D_l)/(\\max_m D_m - \\min_m D_m)}
                                   {\\sum_{l'} (\\max_m D_m - D_{l'})/(\\max_m D_m - \\min_m D_m)}

    The farthest place gets probability 0 and the nearest the largest. A query at equal distance from every place
    gets the uniform distribution, which ``decide(..., "wprob")`` reports as a no-match.
    """
    return wprob_distribution(-finite_matrix("distances", distances))


def cosine_similarities(reference: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Cosine similarity of every query with every reference image, shape ``(n_queries, n_places)``.

    .. math:: C_{ql} = \\frac{Q_q \\cdot R_l}{\\lVert Q_q \\rVert \\, \\lVert R_l \\rVert}
              \\quad (0 \\text{ for an all-zero image})
    """
    ref, qry = _images(reference, queries)

    def unit(a: np.ndarray) -> np.ndarray:
        norm = np.linalg.norm(a, axis=1, keepdims=True)
        return a / np.where(norm > 0, norm, 1.0)

    return unit(qry) @ unit(ref).T


def sad_similarities(distances: np.ndarray) -> np.ndarray:
    """SAD distances as non-negative similarities for :func:`diagonal_sums`, shape ``(n_queries, n_places)``.

    .. math:: S_{ql} = \\max_m D_{qm} - D_{ql}

    The shift is one constant per query frame, so the nearest place and the margin of
    :func:`nearest_neighbour` are those of ``-D``; but a window that reaches beyond the map adds 0 for
    the missing frame, which must not beat a real (negative) score.
    """
    d = finite_matrix("distances", distances)
    return d.max(axis=1, keepdims=True) - d


def diagonal_sums(scores: np.ndarray, k: int, velocity: float = 1.0) -> np.ndarray:
    """Sequence scores of the k most recent frames summed along the velocity-shifted diagonal, ``(n_queries, n_places)``.

    .. math:: A_j(l) = \\sum_{m \\in W_j} S_m\\big(l - v (t_j - t_m)\\big)

    with the window ``W_j`` and the shift (linear interpolation, 0 beyond the map) of
    :func:`vprsnn_export.readout.aggregation.aggregate`; un-normalised (SeqSLAM's sum of scores). A frame whose shifted
    place lies beyond the map adds 0, so the scores must be non-negative similarities (cosine of non-negative images;
    SAD through :func:`sad_similarities`). ``k == 1`` returns a copy of ``scores``.
    """
    s = finite_matrix("scores", scores)
    k = count_at_least("k", k, 1)
    if np.any(s < 0):
        raise InvalidValueError("diagonal_sums needs non-negative similarities (a frame beyond the map adds 0)")
    if k == 1:
        return s.copy()
    n_queries, n_places = s.shape
    t = np.arange(n_queries, dtype=np.float64)  # t_j = j, the frame index
    v = np.full(n_queries, float(velocity))
    out = np.empty_like(s)
    chunk = max(1, _MAX_ELEMENTS // (k * max(1, n_places)))
    for start in range(0, n_queries, chunk):
        queries = np.arange(start, min(start + chunk, n_queries))
        shifted, _ = shift_window(s, queries, k, v, t)
        out[queries] = shifted.sum(axis=1)
    return out


def nearest_neighbour(scores: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Predicted place index and margin confidence per query from similarity scores (larger = closer).

    .. math:: \\hat l_q = \\arg\\max_l S_{ql}, \\qquad c_q = S_{q \\hat l_q} - \\max_{l \\ne \\hat l_q} S_{ql}

    Ties go to the lowest index; a query whose scores are all equal is a no-match (index -1,
    confidence 0); with one place the confidence is 0.
    """
    s = finite_matrix("scores", scores)
    pred = np.argmax(s, axis=1).astype(np.int64)
    if s.shape[1] == 1:
        return pred, np.zeros(s.shape[0])
    top2 = np.partition(s, -2, axis=1)[:, -2:]
    confidence = top2[:, 1] - top2[:, 0]
    flat = s.max(axis=1) == s.min(axis=1)
    pred[flat] = NO_MATCH
    confidence[flat] = 0.0
    return pred, confidence
