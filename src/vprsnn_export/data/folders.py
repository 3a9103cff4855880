"""Data sets as the field ships them: one folder per traversal, frames in time order, ground truth in a file.

Layout (no CSV manifest)::

    myimgs/summer/0001.png 0002.png ...     one subfolder per traversal, image files in natural name order
    myimgs/winter/0001.png 0002.png ...
    myimgs/summer_winter_GT.npy             optional ground truth for a (reference, query) pair

A frame's place id is its index in its traversal (0, 1, ...). With a ground-truth file for a (reference, query)
pair (:mod:`vprsnn_export.data.groundtruth`: LENS's ``<a>_<b>_GT.npy``, VPR-Bench's ``ground_truth_new.npy``
beside ``ref/`` and ``query/``, or a CSV of pairs) every query is scored against the reference frames it names,
whatever the two traversals' lengths and offsets (:func:`query_truth`). Without one, frame ``j`` of every
traversal is place ``j`` ("same index"), which needs equal frame counts: a pair of different lengths is refused
rather than scored by index. Traversals loaded together share their place ids, so hold as many frames.
"""

from __future__ import annotations

import itertools
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
from .groundtruth import agreeing, ground_truth_digest, pair_ground_truth
from .preprocess import normalise_resized, read_grey_image, resize_image


@dataclass(frozen=True)
class FolderGroundTruth:
    """A ground-truth file of a (reference, query) pair of loaded traversals, read and checked."""

    path: Path
    reference: str
    query: str


def is_folder_dataset(path: Path) -> bool:
    """A folder without a manifest whose subfolders hold images."""
    return path.is_dir() and any(child.is_dir() for child in path.iterdir())


def check_every_query_matched(matrix: np.ndarray, queries: np.ndarray, path: Path) -> None:
    """DataError naming the first of ``queries`` (query frame indices) that matches no reference frame."""
    unmatched = queries[~matrix[:, queries].any(axis=0)]
    if unmatched.size:
        raise DataError(
            f"{unmatched.size} queries have no matching reference (first: query {int(unmatched[0])}): "
            "they cannot be scored",
            path,
        )


def query_truth(folder: Path, references: Sequence[str], query: str) -> tuple[np.ndarray, Path] | None:
    """GT[reference frame, query frame] of traversal ``query`` against the reference traversal(s), from the
    ground-truth files beside them (several references must agree); None when the pair has no file and the
    traversals are index-aligned (equal frame counts) or ``query`` is a reference itself. DataError naming the
    folder when the frame counts differ and no file says which frames match (never an index score)."""
    others = [name for name in dict.fromkeys(references) if name != query]
    if not others:
        return None
    absent = [name for name in others if not (folder / name).is_dir()]
    if absent:
        raise DataError(
            f"the model's reference traversal {absent[0]!r} is not a folder here: nothing says how the frames of "
            f"{query!r} align with its places; give the data set it was trained on (--data), with a ground-truth "
            "file when the traversals differ in length",
            folder,
        )
    counts = {name: len(image_files(folder / name)) for name in [query, *others]}
    pairs = (pair_ground_truth(folder, reference, query, counts[reference], counts[query]) for reference in others)
    truth = agreeing([pair for pair in pairs if pair is not None], " (two reference traversals)")
    if truth is None:
        unequal = [name for name in others if counts[name] != counts[query]]
        if unequal:
            raise DataError(
                f"traversal {query!r} holds {counts[query]} frames and reference {unequal[0]!r} "
                f"{counts[unequal[0]]}: they are not index-aligned and no ground-truth file "
                f"({unequal[0]}_{query}_GT.npy or .csv) says which frames match; refusing to score by index",
                folder,
            )
    return truth


def ground_truths(folder: Path, names: Sequence[str], counts: dict[str, int]) -> list[FolderGroundTruth]:
    """The ground truth of every ordered pair of loaded traversals that has a file
    (:func:`~vprsnn_export.data.groundtruth.ground_truth_files`), read strictly and checked."""
    found = []
    for reference, query in itertools.permutations(names, 2):  # the names are distinct
        truth = pair_ground_truth(folder, reference, query, counts[reference], counts[query])
        if truth is not None:
            check_every_query_matched(truth[0], np.arange(counts[query]), truth[1])
            found.append(FolderGroundTruth(truth[1], reference, query))
    return found


def require_traversals(names: Sequence[str], available: Sequence[str], says: str, where: str | Path) -> None:
    """DataError at ``where`` naming the ``names`` not ``available``: ``says`` filled with both lists."""
    missing = [name for name in names if name not in available]
    if missing:
        raise DataError(says.format(", ".join(map(repr, missing)), ", ".join(available) or "none"), where)


def folder_files(folder: Path, names: Sequence[str]) -> dict[str, list[Path]]:
    """Each traversal's frames in time order; DataError naming a missing traversal or unequal counts."""
    available = sorted(child.name for child in folder.iterdir() if child.is_dir())
    require_traversals(names, available, "no traversal folder(s) {}; its traversals are: {}", folder)
    files = {name: image_files(folder / name) for name in names}
    counts = {name: len(paths) for name, paths in files.items()}
    if len(set(counts.values())) > 1:
        raise DataError(
            "the traversals hold different numbers of frames ("
            + ", ".join(f"{name} {count}" for name, count in counts.items())
            + "): traversals loaded together share their place ids; load them one at a time (a ground-truth "
            "file scores a query traversal of another length)",
            folder,
        )
    return files


def folder_fingerprint(files: dict[str, list[Path]], truths: list[FolderGroundTruth]) -> str:
    """sha256 over the traversal names, the frame file names in order and the ground-truth files' sha256."""
    text = "\n".join(f"{name}/{path.name}" for name, paths in files.items() for path in paths)
    return sha256_bytes(text.encode() + "".join(ground_truth_digest(t.path) for t in truths).encode())


def decode_images(
    cells: dict[str, list[tuple[Path, str]]], cfg: PreprocessConfig, progress: bool
) -> dict[str, np.ndarray]:
    """Each traversal's image files (with a context for errors) decoded and preprocessed, (N, inputs) float32."""
    images = {}
    total = sum(len(paths) for paths in cells.values())
    with tqdm(total=total, desc="decoding images", unit="img", file=sys.stderr, disable=not progress) as bar:
        for name, paths in cells.items():
            resized = np.empty((len(paths), cfg.image_size, cfg.image_size), dtype=np.uint8)
            for row, (path, context) in enumerate(paths):
                resized[row] = resize_image(read_grey_image(path, context), cfg.image_size)
                bar.update(1)
            images[name] = normalise_resized(resized, cfg)
    return images
