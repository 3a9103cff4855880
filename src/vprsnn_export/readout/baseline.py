"""The no-learning baseline: sum of absolute differences (SAD) between images.

The same preprocessed (e.g. patch-normalised, flattened) images that the
network sees are compared pixel by pixel with every reference image. The
distances are turned into the same kind of per-query distribution as W+Prob,
so :func:`vprsnn_export.readout.assignment.decide` (strategy ``"wprob"``) and
:func:`vprsnn_export.readout.aggregation.aggregate` serve the baseline
unchanged, and the baseline is scored with exactly the same metrics.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from vprsnn_export.arguments import real_array
from vprsnn_export.errors import InvalidValueError

from .assignment import wprob_distribution

#: Upper bound on the elements of the (chunk, n_places, n_pixels) difference array.
_MAX_ELEMENTS: Final[int] = 4_000_000


def _images(name: str, a: np.ndarray) -> np.ndarray:
    arr = real_array(name, a)
    if arr.ndim != 2:
        raise InvalidValueError(f"{name} must be 2-D (n_images, n_pixels), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidValueError(f"{name} contains NaN or infinite values")
    return arr


def sad_distances(reference: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Sum of absolute differences, shape ``(n_queries, n_places)``.

    .. math:: D_{ql} = \\sum_{p=1}^{D} |Q_{qp} - R_{lp}|

    ``reference``: ``(n_places, D)``, ``queries``: ``(n_queries, D)``, both the
    flattened preprocessed images. Computed over chunks of queries so that the
    ``(chunk, n_places, D)`` difference array stays below ~4M elements.
    """
    ref = _images("reference", reference)
    qry = _images("queries", queries)
    if ref.shape[1] != qry.shape[1]:
        raise InvalidValueError(f"reference images have {ref.shape[1]} pixels but queries have {qry.shape[1]}")
    n_q, n_p = qry.shape[0], ref.shape[0]
    out = np.empty((n_q, n_p), dtype=np.float64)
    per_query = max(1, n_p * ref.shape[1])
    chunk = max(1, _MAX_ELEMENTS // per_query)
    for start in range(0, n_q, chunk):
        stop = min(start + chunk, n_q)
        diff = np.abs(qry[start:stop, None, :] - ref[None, :, :])
        out[start:stop] = diff.sum(axis=2)
    return out


def sad_distribution(distances: np.ndarray) -> np.ndarray:
    """Per-query distribution over places from SAD distances, shape ``(n_queries, n_places)``.

    The similarity is the negated distance, ``s_l = -D_l``; it is min-max
    normalised and L1-normalised exactly like W+Prob (eq. 12-13):

    .. math:: P(l \\mid Q) = \\frac{(\\max_m D_m - D_l)/(\\max_m D_m - \\min_m D_m)}
                                   {\\sum_{l'} (\\max_m D_m - D_{l'})/(\\max_m D_m - \\min_m D_m)}

    The farthest place gets probability 0 and the nearest the largest. A
    query at equal distance from every place gets the uniform distribution,
    which ``decide(..., "wprob")`` reports as a no-match.
    """
    d = real_array("distances", distances)
    if d.ndim != 2:
        raise InvalidValueError(f"distances must be 2-D (n_queries, n_places), got shape {d.shape}")
    return wprob_distribution(-d)
