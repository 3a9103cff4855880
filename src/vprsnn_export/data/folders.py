"""Data sets as the field ships them: one folder per traversal, frames in time order, ground truth in a file.

Layout (no CSV manifest)::

    myimgs/summer/0001.png 0002.png ...     one subfolder per traversal, image files in natural name order
    myimgs/winter/0001.png 0002.png ...
    myimgs/summer_winter_GT.npy             optional ground truth for a (reference, query) pair

The place of a frame is its index in its traversal (0, 1, ...): frame ``j`` of every traversal is
place ``j`` ("same index"), so every traversal holds the same number of frames. ``--places`` /
``--subset`` select by that index. A ground-truth file is checked against that alignment:

* ``<reference>_<query>_GT.npy``, a 2-D 0/1 matrix ``GT[reference, query]`` (the LENS layout), or a
  1-D object array with, per query, the list of matching reference indices (VPR-Bench);
* ``<reference>_<query>_GT.csv`` with columns ``query,reference`` (one row per matching pair).

For every query ``j`` the distance to its nearest matching reference must be at most the largest
such distance over the queries, ``W = max_j min_{r in GT(j)} |r - j|``; the loader reports ``W``
(:attr:`FolderGroundTruth.window`) so that ``--match-window W`` scores every query against the
file's matches. A query with no match, or ground truth that is not close to the index alignment
(``W`` above :data:`MAX_WINDOW`), is a DataError: this version scores against index-aligned places.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..config import PreprocessConfig
from ..errors import DataError
from ..io.fileio import sha256_bytes
from .frames import image_files
from .groundtruth import pair_ground_truth
from .preprocess import normalise_resized, read_grey_image, resize_image

MAX_WINDOW = 50  # places: ground truth further from the index alignment than this is not supported


@dataclass(frozen=True)
class FolderGroundTruth:
    """A ground-truth file of a (reference, query) pair, checked against the index alignment."""

    path: Path
    reference: str
    query: str
    window: int  # W: every query has a matching reference within +-W of its own index


def is_folder_dataset(path: Path) -> bool:
    """A folder without a manifest whose subfolders hold images."""
    return path.is_dir() and any(child.is_dir() for child in path.iterdir())


def traversal_names(folder: Path) -> list[str]:
    return sorted(child.name for child in folder.iterdir() if child.is_dir())


def alignment_window(matrix: np.ndarray, path: Path) -> int:
    """W = max_j min_{r : GT[r, j]} |r - j|; DataError for a query without a match or W > MAX_WINDOW."""
    n_reference, n_query = matrix.shape
    unmatched = np.flatnonzero(~matrix.any(axis=0))
    if unmatched.size:
        raise DataError(f"{unmatched.size} queries have no matching reference (first: query {unmatched[0]})", path)
    distance = np.abs(np.arange(n_reference)[:, None] - np.arange(n_query)[None, :]).astype(np.float64)
    nearest = np.where(matrix, distance, np.inf).min(axis=0)
    window = int(nearest.max())
    if window > MAX_WINDOW:
        worst = int(np.argmax(nearest))
        raise DataError(
            f"query {worst}'s nearest match is {window} frames from its own index: this version scores folder "
            f"data sets whose frame j is place j (within +-{MAX_WINDOW})",
            path,
        )
    return window


def ground_truths(folder: Path, names: Sequence[str], counts: dict[str, int]) -> list[FolderGroundTruth]:
    """The ground truth of every ordered pair of loaded traversals that has a file
    (:func:`~vprsnn_export.data.groundtruth.ground_truth_files`), read strictly and checked."""
    found = []
    for reference in names:
        for query in names:
            truth = (
                None
                if reference == query
                else pair_ground_truth(folder, reference, query, counts[reference], counts[query])
            )
            if truth is not None:
                matrix, path = truth
                found.append(FolderGroundTruth(path, reference, query, alignment_window(matrix, path)))
    return found


def folder_files(folder: Path, names: Sequence[str]) -> dict[str, list[Path]]:
    """Each traversal's frames in time order; DataError naming a missing traversal or unequal counts."""
    available = traversal_names(folder)
    missing = [name for name in names if name not in available]
    if missing:
        raise DataError(
            f"no traversal folder(s) {', '.join(repr(m) for m in missing)}; its traversals are: "
            f"{', '.join(available) or 'none'}",
            folder,
        )
    files = {name: image_files(folder / name) for name in names}
    counts = {name: len(paths) for name, paths in files.items()}
    if len(set(counts.values())) > 1:
        raise DataError(
            "the traversals hold different numbers of frames ("
            + ", ".join(f"{name} {count}" for name, count in counts.items())
            + "): frame j of every traversal must be place j",
            folder,
        )
    return files


def folder_fingerprint(files: dict[str, list[Path]], truths: list[FolderGroundTruth]) -> str:
    """sha256 over the traversal names, the frame file names in order and the ground-truth files' bytes."""
    text = "\n".join(f"{name}/{path.name}" for name, paths in files.items() for path in paths)
    return sha256_bytes(text.encode() + b"".join(t.path.read_bytes() for t in truths))


def decode_frames(
    files: dict[str, list[Path]], selected: np.ndarray, cfg: PreprocessConfig, progress: bool
) -> dict[str, np.ndarray]:
    """The selected frames of each traversal, preprocessed (N, inputs) float32."""
    size = cfg.image_size
    images = {}
    with tqdm(
        total=len(selected) * len(files), desc="decoding images", unit="img", file=sys.stderr, disable=not progress
    ) as bar:
        for name, paths in files.items():
            resized = np.empty((len(selected), size, size), dtype=np.uint8)
            for row, index in enumerate(selected.tolist()):
                resized[row] = resize_image(read_grey_image(paths[index], f"frame {index} of traversal {name!r}"), size)
                bar.update(1)
            images[name] = normalise_resized(resized, cfg)
    return images
