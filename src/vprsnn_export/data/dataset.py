"""Place manifests, place selection and the preprocessed image set.

A data set is a place manifest, a folder of traversal folders (:mod:`vprsnn_export.data.folders`: frames in
time order, frame j is place j, optional ground-truth files) or arrays (:meth:`Dataset.from_arrays`). A place
manifest is a CSV with one row per place: an integer ``place_id`` column and one column per traversal holding
an image path relative to the CSV's folder; the same place id in two traversals is the same place.

``load_dataset`` resolves ``--data`` (a manifest, a folder holding ``places.csv``, a folder of traversal
folders, or ``synthetic[:N]``), applies the selection (``--subset`` file or ``--places START:COUNT[:STRIDE]``),
then decodes and preprocesses only the selected images once.

Over 400 lines because it is one concept, the data set as the commands see it: the three sources
(manifest, traversal folders, synthetic route) share one selection (subset file, ``--places`` or ids)
and one CSV reader, whose checks are the edge where manifest and subset files enter.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..arguments import MAX_PLACE_ID, ascii_uint, check_place_ids, require_type
from ..config import PreprocessConfig
from ..errors import DataError, InvalidValueError, VprError
from ..io.fileio import is_readable_file, sha256_bytes
from .folders import (
    FolderGroundTruth,
    check_every_query_matched,
    decode_images,
    folder_files,
    folder_fingerprint,
    ground_truths,
    is_folder_dataset,
    query_truth,
    require_traversals,
)
from .frames import image_files
from .groundtruth import GT_SUFFIXES, VPR_BENCH_GT, ground_truth_files
from .preprocess import preprocess_images, read_grey_image
from .synthetic import (
    DEFAULT_PLACES,
    IMAGE_HEIGHT,
    IMAGE_WIDTH,
    SYNTHETIC_TRAVERSALS,
    synthetic_fingerprint,
    synthetic_route,
)
from .truth import GroundTruth, Query, window

PLACE_ID = "place_id"
MANIFEST_NAME = "places.csv"
SYNTHETIC = "synthetic"
Selection = str | Path | Sequence[int] | np.ndarray | None
"""A subset CSV (a ``place_id`` column, in order), the place ids themselves, or None for every place."""
NORDLAND_HINT = "the Nordland data lives under ../shared/data/nordland_64x32_summer_winter (relative to the repository)"


@dataclass(frozen=True, eq=False)
class Dataset:
    """Preprocessed images of the selected places, one aligned array per traversal."""

    source: str  # manifest path as given, or "synthetic[:N]"
    manifest_sha256: str  # sha256 of the manifest file bytes, or the synthetic fingerprint
    place_ids: np.ndarray  # (N,) int64, in selection order
    images: dict[str, np.ndarray]  # traversal -> (N, image_size**2) float32, row k is place_ids[k]
    ground_truth: tuple[FolderGroundTruth, ...] = ()  # a folder data set's checked ground-truth files

    @classmethod
    def from_arrays(
        cls,
        images: Mapping[str, np.ndarray],
        cfg: PreprocessConfig,
        place_ids: Sequence[int] | np.ndarray | None = None,
        *,
        source: str = "arrays",
    ) -> Dataset:
        """A data set from greyscale frames held in memory: ``images`` maps each traversal to ``(N, H, W)`` uint8
        frames, row k of every traversal being place ``place_ids[k]`` (default 0..N-1), preprocessed with ``cfg``
        like loaded images; ``manifest_sha256`` hashes the pixels and ids.

        ``vx.Dataset.from_arrays({"day": day, "night": night}, vx.Config().preprocess)``
        """
        names = _check_traversals(list(images))
        arrays = {name: np.asarray(images[name]) for name in names}
        counts = {name: len(array) for name, array in arrays.items()}
        if len(set(counts.values())) != 1 or 0 in counts.values():
            raise DataError(f"every traversal needs the same, non-zero number of frames; got {counts}", source)
        n = next(iter(counts.values()))
        ids = np.arange(n, dtype=np.int64) if place_ids is None else np.asarray(place_ids, dtype=np.int64).reshape(-1)
        if ids.shape != (n,) or len(np.unique(ids)) != n or (ids.size and ids.min() < 0):
            raise InvalidValueError(f"place_ids must be {n} distinct non-negative integers, got shape {ids.shape}")
        digest = sha256_bytes(b"".join(arrays[name].tobytes() for name in names) + ids.tobytes())
        processed = {name: preprocess_images(array, cfg) for name, array in arrays.items()}
        return cls(source=source, manifest_sha256=digest, place_ids=ids, images=processed)

    @property
    def n_places(self) -> int:
        return len(self.place_ids)

    @property
    def traversals(self) -> tuple[str, ...]:
        return tuple(self.images)

    def traversal(self, name: str) -> np.ndarray:
        """The ``(N, image_size**2)`` images of traversal ``name``; DataError listing the loaded ones if absent."""
        if name not in self.images:
            raise DataError(
                f"traversal {name!r} is not loaded from {self.source}; available: {', '.join(self.images) or 'none'}"
            )
        return self.images[name]

    def query(self, name: str, references: Sequence[str], match_window: int | None = None) -> Query:
        """Traversal ``name`` as a query of a network trained on ``references``, with the truth that judges it,
        built once: the data set's ground truth when it has one (then ``match_window``, which is for
        index-aligned data, is refused), else ``match_window`` places around each query's own id (None: exact)."""
        truth = scoring_truth(self, references, name)
        if truth is not None and match_window:
            raise window_beside_truth(match_window, truth.source)
        return Query(name, self.traversal(name), self.place_ids, window(match_window) if truth is None else truth)


def window_beside_truth(match_window: int, truth_file: str | Path) -> InvalidValueError:
    """The one refusal of --match-window on data that a ground-truth file scores."""
    return InvalidValueError(
        f"--match-window {match_window}: {truth_file} says which reference frames match each query; "
        "--match-window is for index-aligned data without a ground-truth file"
    )


@dataclass(frozen=True)
class Manifest:
    """A parsed place manifest: its resolved path, content hash, header and rows by place id."""

    path: Path
    sha256: str
    columns: tuple[str, ...]
    rows: dict[int, tuple[int, dict[str, str]]]  # place_id -> (CSV line number, row)


MAX_PLACES = 10_000_000  # a selection larger than this is a typing error, not a route
MAX_SYNTHETIC_PLACES = 100_000


def parse_places(spec: str) -> tuple[int, int, int]:
    """``"START:COUNT[:STRIDE]"`` -> ``(start, count, stride)``: place ids ``start + k * stride``, k = 0..count-1.

    START >= 0, COUNT >= 1, STRIDE >= 1 (default 1); anything else is an InvalidValueError.
    """
    numbers = [ascii_uint(part.strip()) for part in str(spec).strip().split(":")]
    start, count, stride = (number or 0 for number in [*numbers, 1, 1][:3])  # STRIDE defaults to 1
    malformed = len(numbers) not in (2, 3) or None in numbers
    if malformed or not 1 <= count <= MAX_PLACES or stride < 1 or start + (count - 1) * stride > MAX_PLACE_ID:
        raise InvalidValueError(
            f"--places {spec!r}: expected START:COUNT[:STRIDE] with integers START >= 0, COUNT >= 1, STRIDE >= 1"
        )
    return start, count, stride


def parse_synthetic(data: str) -> int | None:
    """``"synthetic"`` -> 60 places, ``"synthetic:N"`` -> N, anything else -> None (a path)."""
    if data == SYNTHETIC:
        return DEFAULT_PLACES
    if not data.startswith(SYNTHETIC + ":"):
        return None
    count = ascii_uint(data[len(SYNTHETIC) + 1 :])
    if count is None or not 1 <= count <= MAX_SYNTHETIC_PLACES:
        raise InvalidValueError(
            f"--data {data!r}: expected synthetic or synthetic:N with N from 1 to {MAX_SYNTHETIC_PLACES}"
        )
    return count


def selection_record(subset: str | Path | None, places: str | None) -> dict[str, str | None]:
    """The place selection as a checkpoint stores it: an absolute subset path (so the checkpoint can be
    used from another directory) or a START:COUNT[:STRIDE] spec."""
    return {"subset": str(Path(subset).resolve()) if subset else None, "places": places}


def scoring_truth(dataset: Dataset, references: Sequence[str], query: str) -> GroundTruth | None:
    """How the queries of traversal ``query`` are scored against a network trained on ``references``: the data
    set's ground truth in place ids (:func:`vprsnn_export.data.folders.query_truth`) for a folder data set with a
    ground-truth file; None for same-index data (a manifest, the synthetic route, a folder pair of equal lengths
    without a file). DataError naming the file when a selected query has no match, or the folder when its
    traversals are not index-aligned and no file says how they match."""
    folder = Path(dataset.source)
    if parse_synthetic(dataset.source) is not None:
        return None
    if not _is_folders(folder):
        manifest_folder = folder if folder.is_dir() else folder.parent
        beside = [path for reference in references for path, _ in ground_truth_files(manifest_folder, reference, query)]
        if beside:  # docs/data.md: a manifest aligns places by index; a ground truth beside it would say otherwise
            raise DataError(
                f"this data set is read by its manifest ({MANIFEST_NAME}: places aligned by index), but "
                f"{beside[0].name} beside it says which references match each query: which one scores the queries "
                "is ambiguous; move one of the two aside",
                manifest_folder,
            )
        return None
    truth = query_truth(folder, _check_traversals(references), query)
    if truth is not None:
        check_every_query_matched(truth[0], dataset.place_ids, truth[1])
        return GroundTruth(truth[0], str(truth[1]))
    return None


def dataset_files(dataset: Dataset, *subsets: object) -> tuple[Path, ...]:
    """The files a data set was read from that no output of the same run may replace: its manifest, every
    ground-truth file of a folder data set (:data:`~vprsnn_export.data.groundtruth.GT_SUFFIXES`, VPR-Bench's
    file) and the given subset files (None and place-id sequences are skipped)."""
    source = Path(dataset.source)
    files = [Path(s) for s in subsets if isinstance(s, str | Path) and str(s).strip()]
    if source.is_file():
        files.append(source)
    elif source.is_dir():
        files += [p for suffix in GT_SUFFIXES for p in source.glob(f"*{suffix}")]
        files += [source / VPR_BENCH_GT, source / MANIFEST_NAME]
    return tuple(files)


def reference_frame_shape(record: Mapping[str, object], traversals: Sequence[str]) -> tuple[int, int] | None:
    """(height, width) of the first reference image a network was trained on (its data ``record``): the size a
    stream of frames is expected to have. None when the data source is not readable here (nothing to compare)."""
    source = _optional_str(record.get("source"))
    if source is None or not traversals:
        return None
    try:
        if parse_synthetic(source) is not None:
            return IMAGE_HEIGHT, IMAGE_WIDTH
        folder = Path(source)
        if _is_folders(folder):
            first = image_files(folder / traversals[0])[0]
        else:
            manifest = read_manifest(source)
            first = manifest.path.parent / next(iter(manifest.rows.values()))[1].get(traversals[0], "")
        shape = read_grey_image(first).shape
    except (VprError, OSError, StopIteration):
        return None
    return int(shape[0]), int(shape[1])


def data_selection(
    record: Mapping[str, object],
    source: str | Path | None = None,
    subset: str | Path | None = None,
    places: str | None = None,
) -> tuple[str, str | None, str | None]:
    """(data source, subset, places): those given here, else those of a checkpoint's or model's ``data`` record
    (its subset and places only when neither is given); DataError when neither names a source."""
    if subset is None and places is None:
        subset, places = _optional_str(record.get("subset")), _optional_str(record.get("places"))
    chosen = source if source is not None else _optional_str(record.get("source"))
    if chosen is None:
        raise DataError("no data source: give --data (the checkpoint records none)")
    return str(chosen), _optional_str(subset), places


def load_selection(
    data: Mapping[str, object],
    traversals: Sequence[str],
    cfg: PreprocessConfig,
    *,
    source: str | Path | None = None,
    subset: str | Path | None = None,
    places: str | None = None,
    progress: bool = False,
) -> Dataset:
    """The places a checkpoint or model was made from (its ``data`` record), or the selection given here
    (:func:`data_selection`)."""
    chosen, subset, places = data_selection(data, source, subset, places)
    return load_dataset(chosen, traversals, cfg, subset=subset, places=places, progress=progress)


def select_places(dataset: Dataset, place_ids: Sequence[int] | np.ndarray) -> Dataset:
    """The places with these ids, in this order (a DataError names ids the data set does not hold)."""
    require_type("dataset", dataset, Dataset)
    wanted = check_place_ids(place_ids)
    if wanted.size == 0:
        raise InvalidValueError("place_ids must name at least one place")
    unique, counts = np.unique(wanted, return_counts=True)
    if (counts > 1).any():
        raise InvalidValueError(f"place_ids names place {int(unique[counts > 1][0])} more than once")
    position = {int(pid): row for row, pid in enumerate(dataset.place_ids)}
    missing = [int(pid) for pid in wanted if int(pid) not in position]
    if missing:
        raise DataError(f"place id(s) {missing[:5]} are not in {dataset.source}")
    rows = np.asarray([position[int(pid)] for pid in wanted], dtype=np.int64)
    return replace(dataset, place_ids=wanted, images={name: array[rows] for name, array in dataset.images.items()})


def _optional_str(value: object) -> str | None:
    return None if value is None else str(value)


def _is_folders(path: Path) -> bool:
    """A folder of traversal folders (:func:`~vprsnn_export.data.folders.is_folder_dataset`) without a manifest."""
    return is_folder_dataset(path) and not (path / MANIFEST_NAME).is_file()


def load_dataset(
    data: str | Path,
    traversals: Sequence[str],
    cfg: PreprocessConfig,
    *,
    subset: Selection = None,
    places: str | None = None,
    progress: bool = False,
) -> Dataset:
    """Load, select, decode and preprocess; every expected problem is a DataError/InvalidValueError naming the file
    (``cfg``: a config's ``preprocess`` settings)."""
    require_type("cfg", cfg, PreprocessConfig)
    names = _check_traversals(traversals)
    if subset is not None and places is not None:
        raise InvalidValueError("give either --subset or --places, not both")
    n_synthetic = parse_synthetic(data) if isinstance(data, str) else None
    if n_synthetic is not None:  # the synthetic route: place j is image j of every traversal
        require_traversals(
            names, SYNTHETIC_TRAVERSALS, "the synthetic route has no traversal(s) {}; available: {}", data
        )
        selected = _select(np.arange(n_synthetic, dtype=np.int64), subset, places, str(data))
        route = synthetic_route(n_synthetic, names)
        images = {name: preprocess_images(route[name][selected], cfg) for name in names}
        return Dataset(str(data), synthetic_fingerprint(n_synthetic, SYNTHETIC_TRAVERSALS), selected, images)
    folder = Path(data)
    if _is_folders(folder):  # traversal folders (:mod:`vprsnn_export.data.folders`): place j is frame j of each
        files = folder_files(folder, names)
        truths = ground_truths(folder, names, {name: len(paths) for name, paths in files.items()})
        selected = _select(np.arange(len(files[names[0]]), dtype=np.int64), subset, places, str(folder))
        cells = {
            name: [(paths[i], f"frame {i} of traversal {name!r}") for i in selected.tolist()]
            for name, paths in files.items()
        }
        images = decode_images(cells, cfg, progress)
        return Dataset(str(folder.resolve()), folder_fingerprint(files, truths), selected, images, tuple(truths))
    manifest = read_manifest(data)
    require_traversals(
        names, manifest.columns, "traversal column(s) {} not in the manifest; its columns are: {}", manifest.path
    )
    selected = _select(np.array([*manifest.rows], dtype=np.int64), subset, places, str(manifest.path))
    images = decode_images({name: _image_paths(manifest, name, selected) for name in names}, cfg, progress)
    # stored resolved, so a checkpoint made here still finds its data when used from another directory
    return Dataset(str(manifest.path.resolve()), manifest.sha256, selected, images)


def read_manifest(data: str | Path) -> Manifest:
    """Resolve ``data`` (a CSV, or a folder holding ``places.csv``) and parse it; DataError on any defect."""
    path = Path(data)
    if path.is_dir():
        if not (path / MANIFEST_NAME).is_file():
            raise DataError(
                f"this folder has no {MANIFEST_NAME} place manifest and no traversal folders of images", path
            )
        path = path / MANIFEST_NAME
    hint = f"; {NORDLAND_HINT}" if "nordland" in str(path).lower() or "shared" in path.parts else ""
    missing = f"no such place manifest (a CSV file, or a folder holding {MANIFEST_NAME}){hint}"
    raw, columns, rows = _read_csv(path, "place manifest", missing, "the place manifest lists no places")
    return Manifest(path=path, sha256=sha256_bytes(raw), columns=columns, rows=rows)


def _check_traversals(traversals: Sequence[str]) -> tuple[str, ...]:
    if isinstance(traversals, str):
        traversals = (traversals,)
    names = tuple(dict.fromkeys(str(name).strip() for name in traversals))
    if not names or "" in names:
        raise InvalidValueError(f"expected one or more traversal names, got {list(traversals)!r}")
    if PLACE_ID in names:
        raise InvalidValueError(f"{PLACE_ID!r} is the place id column, not a traversal")
    return names


def _read_csv(
    path: Path, kind: str, missing: str, empty: str
) -> tuple[bytes, tuple[str, ...], dict[int, tuple[int, dict[str, str]]]]:
    """Bytes, header and rows by place id, in file order (place_id -> (line number, row)) of a UTF-8 CSV with a
    ``place_id`` column, names and cells stripped of spaces; DataError on a defect or a repeated place id, and
    the messages ``missing`` for no readable file and ``empty`` for no row."""
    if not is_readable_file(path):
        raise DataError(missing, path)
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise DataError(f"the {kind} is not UTF-8 CSV text ({exc})", path) from None
    try:
        reader = csv.reader(io.StringIO(text, newline=""))
        header = next(reader, None)
        columns = tuple(name.strip() for name in header or ())
        duplicated = sorted({name for name in columns if columns.count(name) > 1})
        for refused, problem in (
            (header is None, f"the {kind} is empty (no header row)"),
            (duplicated, f"the {kind} repeats column(s) {', '.join(duplicated)}"),
            (
                PLACE_ID not in columns,
                f"the {kind} has no {PLACE_ID!r} column; its columns are: {', '.join(columns) or 'none'}",
            ),
        ):
            if refused:
                raise DataError(problem, path)
        rows: dict[int, tuple[int, dict[str, str]]] = {}
        for cells in reader:
            if not any(cell.strip() for cell in cells):
                continue
            record = {name: cell.strip() for name, cell in zip(columns, cells, strict=False)}
            value = record.get(PLACE_ID)
            place = ascii_uint((value or "").strip(" \t"))
            if place is None:
                raise DataError(f"line {reader.line_num}: place_id {value!r} is not an integer", path) from None
            if not 0 <= place <= MAX_PLACE_ID:
                raise DataError(f"line {reader.line_num}: place_id {place} is outside 0..2**53", path)
            if place in rows:
                raise DataError(f"duplicate place_id {place} on lines {rows[place][0]} and {reader.line_num}", path)
            rows[place] = (reader.line_num, record)
    except csv.Error as exc:
        raise DataError(f"the {kind} is not valid CSV ({exc})", path) from None
    if not rows:
        raise DataError(empty, path)
    return raw, columns, rows


def _select(available: np.ndarray, subset: Selection, places: str | None, source: str) -> np.ndarray:
    """Selected place ids in selection order; every one must be in ``available``."""
    if isinstance(subset, str | Path):  # a subset CSV's place_id column, in file order
        missing = "no such subset file (a CSV with a place_id column)"
        _, _, rows = _read_csv(Path(subset), "subset file", missing, "empty selection: the subset file lists no places")
        selected = np.array([*rows], dtype=np.int64)
        where = f"subset file {subset}"
    elif subset is not None:
        selected = np.asarray(subset, dtype=np.int64).reshape(-1)
        where = "the given place ids"
    elif places is not None:
        start, count, stride = parse_places(places)
        selected = start + stride * np.arange(count, dtype=np.int64)
        where = f"--places {places}"
    else:
        selected = available.copy()
        where = source
    if not len(selected):
        raise DataError(f"empty selection ({where})", source)
    absent = selected[~np.isin(selected, available)]
    if len(absent):
        shown = ", ".join(str(int(place)) for place in absent[:5]) + (", ..." if len(absent) > 5 else "")
        raise DataError(
            f"{len(absent)} selected place id(s) from {where} are not in the data ({shown}); "
            f"it holds {len(available)} places, ids {int(available.min())}..{int(available.max())}",
            source,
        )
    return selected


def _image_paths(manifest: Manifest, name: str, selected: np.ndarray) -> list[tuple[Path, str]]:
    """Image path and a context string for every selected place of one traversal; DataError on an empty cell."""
    for place in selected.tolist():
        line, record = manifest.rows[place]
        if not record.get(name):
            raise DataError(f"line {line}: empty {name!r} image cell for place_id {place}", manifest.path)
    where = f"traversal {name!r} of {manifest.path}"
    return [(manifest.path.parent / manifest.rows[p][1][name], f"place_id {p}, {where}") for p in selected.tolist()]
