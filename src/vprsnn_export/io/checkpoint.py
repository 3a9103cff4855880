"""The float checkpoint: weights, thresholds, calibration, full config and provenance in one file.

Format: an npz container (no pickle, :mod:`vprsnn_export.io.fileio`) with arrays ``weights`` (inputs, neurons)
float32, ``thresholds`` (neurons,) float32, ``calibration`` (neurons, places) int64 = S^R and
``reference_place_ids`` (places,) int64 (a sparse S^R, :func:`vprsnn_export.trainer.calibrate.calibrate` on a
long route, as its CSR arrays ``calibration_data`` int64, ``calibration_indices`` and ``calibration_indptr``
int64 instead of ``calibration``), and a JSON header holding the config, the seed, the data provenance
(source, manifest sha256, reference traversals, place selection), the training history and the package version.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
from scipy import sparse

from ..arguments import require_path
from ..config import Config
from ..data.dataset import MAX_PLACE_ID, parse_places, parse_synthetic
from ..errors import InvalidValueError, ModelFileError, VprError
from ..network.modules import ensemble_neurons
from ..version import __version__
from .fileio import read_container, sha256_file, write_container

FORMAT = "vprsnn-checkpoint"
FORMAT_VERSION = 1
#: The arrays of a checkpoint file, in the order written, with the dtype each is written as.
ARRAYS = {"weights": np.float32, "thresholds": np.float32, "calibration": np.int64, "reference_place_ids": np.int64}
#: A sparse S^R's arrays (CSR), in place of ``calibration``.
SPARSE_CALIBRATION = ("calibration_data", "calibration_indices", "calibration_indptr")
#: History fields that measure the machine, not the network: left out of files so that two
#: runs of the same seed and data write byte-identical checkpoints (and identical sha256).
TIMING_FIELDS = ("seconds",)


@dataclass
class Checkpoint:
    config: Config
    weights: np.ndarray
    thresholds: np.ndarray
    calibration: np.ndarray | sparse.csr_array  # S^R (neurons, places): dense, or CSR on a long route
    reference_place_ids: np.ndarray
    reference_traversals: list[str]
    data: dict[str, Any]  # source, manifest_sha256, subset, places
    history: list[dict] = field(default_factory=list)
    version: str = __version__


def checkpoint_header(ckpt: Checkpoint) -> dict[str, Any]:
    """The JSON header of a checkpoint file (also embedded in exported NIR graphs)."""
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "package_version": ckpt.version,
        "config": ckpt.config.to_dict(),
        "seed": ckpt.config.seed,
        "reference_traversals": list(ckpt.reference_traversals),
        "data": ckpt.data,
        "history": [{k: v for k, v in entry.items() if k not in TIMING_FIELDS} for entry in ckpt.history],
    }


def save_checkpoint(path: str | Path, ckpt: Checkpoint) -> Path:
    """Validate and write a checkpoint atomically (npz arrays + JSON header with the whole config); returns the path."""
    path = require_path("path", path)
    validate_checkpoint(ckpt, path)
    meta = checkpoint_header(ckpt)
    check_header(meta, path)  # the reader's own checks: nothing is written that load_checkpoint refuses
    arrays: dict[str, np.ndarray] = {}
    for name, dtype in ARRAYS.items():  # in order: a dense checkpoint's bytes do not depend on the sparse case
        value = getattr(ckpt, name)
        if name == "calibration" and sparse.issparse(value):  # its data, indices and indptr
            arrays |= {
                key: getattr(value, key.removeprefix("calibration_")).astype(np.int64) for key in SPARSE_CALIBRATION
            }
        else:
            arrays[name] = value.astype(dtype)
    return write_container(path, meta, arrays)


def load_checkpoint(path: str | Path) -> Checkpoint:
    """Read and validate a checkpoint (shapes, dtypes, finiteness, config); ModelFileError names the file and the problem."""
    meta, arrays = read_container(path, "checkpoint")  # the path as given: '' is named as empty, not '.'
    path = Path(path)
    config, traversals, data, history = check_header(meta, path)
    if "calibration" not in arrays and {*SPARSE_CALIBRATION, "reference_place_ids"} <= set(arrays):
        values, indices, indptr = (arrays.pop(name) for name in SPARSE_CALIBRATION)  # a long route's CSR S^R
        places = validate_reference_ids(arrays["reference_place_ids"], path)
        try:  # (neurons, places) from its config and place ids, its structure checked in full
            csr = sparse.csr_array((values, indices, indptr), shape=(ensemble_neurons(config, places), places))
            csr.check_format(full_check=True)
        except (ValueError, TypeError, OverflowError, VprError) as exc:
            raise ModelFileError(f"the sparse calibration arrays do not form a CSR array ({exc})", path) from None
        arrays["calibration"] = csr
    if set(ARRAYS) - set(arrays):
        raise ModelFileError(f"checkpoint lacks arrays {sorted(set(ARRAYS) - set(arrays))}", path)
    weights, thresholds, calibration, ids = (arrays[name] for name in ARRAYS)
    version = str(meta.get("package_version", "unknown"))
    ckpt = Checkpoint(config, weights, thresholds, calibration, ids, traversals, data, history, version)
    validate_checkpoint(ckpt, path)
    return ckpt


def check_header(
    meta: dict[str, Any], path: str | Path
) -> tuple[Config, list[str], dict[str, str | None], list[dict[str, Any]]]:
    """A checkpoint header's config, reference traversals, data record and history; ModelFileError naming ``path``.
    Run by the reader on what it reads and by the writer on what it is about to write."""
    for key, expected, problem in (
        ("format", FORMAT, "not a vprsnn checkpoint (format {!r})"),
        ("format_version", FORMAT_VERSION, "unsupported checkpoint format version {!r}"),
    ):
        if meta.get(key) != expected:
            raise ModelFileError(problem.format(meta.get(key)), path)
    try:
        config = Config.from_dict(meta["config"])
    except (KeyError, VprError) as exc:
        raise ModelFileError(f"invalid config in checkpoint ({exc})", path) from None
    traversals, data = reference_header(meta, path)
    history = meta.get("history", [])
    if not isinstance(history, list) or not all(isinstance(entry, dict) for entry in history):
        raise ModelFileError("history must be a list of per-epoch mappings", path)
    return config, traversals, data, history


def reference_header(meta: dict[str, Any], path: str | Path) -> tuple[list[str], dict[str, str | None]]:
    """The header's reference traversals (a non-empty list of names) and data record (a mapping of strings), for
    checkpoints and fixed-point models (which also need a string ``package_version``); ModelFileError naming ``path``
    otherwise, for the first defect in the order checked."""

    def fail(problem: str) -> NoReturn:
        raise ModelFileError(problem, path) from None

    if not isinstance(meta.get("package_version", "unknown"), str):
        fail(f"package_version must be a version string, got {meta['package_version']!r}")
    traversals = meta.get("reference_traversals", [])
    names = traversals if isinstance(traversals, list) and all(isinstance(t, str) and t for t in traversals) else []
    if not names or len(set(names)) != len(names):
        fail("reference_traversals must be a non-empty list of distinct traversal names")
    data = meta.get("data", {})
    if not isinstance(data, dict) or not all(v is None or isinstance(v, str) for v in data.values()):
        fail("data must be a mapping of names to strings (source, selection)")
    try:
        if data.get("places"):
            parse_places(data["places"])
        if str(data.get("source", "")).startswith("synthetic"):
            parse_synthetic(data["source"])
    except InvalidValueError as exc:
        fail(f"the data record is invalid ({exc})")
    return list(names), dict(data)


def validate_reference_ids(ids: np.ndarray, path: str | Path) -> int:
    """The number of reference places: ``ids`` must be a non-empty 1-D array of distinct non-negative integers."""
    ids = np.asarray(ids)
    if ids.ndim != 1 or ids.size == 0 or not np.issubdtype(ids.dtype, np.integer):
        raise ModelFileError("reference_place_ids must be a non-empty 1-D integer array", path)
    if np.unique(ids).size != ids.size or np.any(ids < 0) or np.any(ids > MAX_PLACE_ID):
        raise ModelFileError(f"reference_place_ids must be distinct place ids from 0 to {MAX_PLACE_ID}", path)
    return int(ids.size)


def checkpoint_sha256(path: str | Path) -> str:
    """sha256 of the checkpoint file's bytes: the identity every model, export and report derived from it records."""
    return sha256_file(path)


def validate_checkpoint(ckpt: Checkpoint, path: str | Path = "<checkpoint>") -> None:
    """Shapes agree with the config, dtypes are numeric, values finite and in range: ModelFileError naming ``path``
    for the first defect in the order checked (each check may assume the ones before it passed)."""
    path = Path(path)

    def fail(problem: str) -> NoReturn:
        raise ModelFileError(problem, path)

    if not isinstance(ckpt, Checkpoint):
        fail(f"not a Checkpoint: a {type(ckpt).__name__}")
    if isinstance(ckpt.reference_traversals, str) or not isinstance(ckpt.reference_traversals, list | tuple):
        fail(f"reference_traversals must be a list of traversal names, got {ckpt.reference_traversals!r}")
    n_places = validate_reference_ids(ckpt.reference_place_ids, path)
    n_neurons = ensemble_neurons(ckpt.config, n_places)  # M n: every module's neurons side by side
    for name, shape in (("weights", (ckpt.config.network.n_inputs, n_neurons)), ("thresholds", (n_neurons,))):
        array = getattr(ckpt, name)
        if array.shape != shape:
            fail(f"{name} has shape {array.shape}, expected {shape} from its config")
        if not np.issubdtype(array.dtype, np.floating):
            fail(f"{name} has dtype {array.dtype}, expected float32")
        if not np.all(np.isfinite(array)):
            fail(f"{name} contains NaN or infinite values")
    if np.any(ckpt.weights < 0):
        fail("weights contain negative values (STDP weights are non-negative)")
    if np.any(ckpt.weights > ckpt.config.stdp.w_max * (1 + 1e-6)):
        fail(f"weights exceed the config's w_max = {ckpt.config.stdp.w_max}")
    if np.any(ckpt.thresholds <= 0):
        fail("thresholds must be positive")
    ceiling = max(ckpt.config.homeostasis.theta_max, ckpt.config.network.theta_init)
    if np.any(ckpt.thresholds > ceiling * (1 + 1e-6)):
        fail(f"thresholds exceed the config's theta_max / theta_init ({ceiling})")
    if ckpt.calibration.shape != (n_neurons, n_places):
        fail(f"calibration has shape {ckpt.calibration.shape}, expected {(n_neurons, n_places)}")
    values = np.asarray(ckpt.calibration.data if sparse.issparse(ckpt.calibration) else ckpt.calibration)
    if not np.issubdtype(ckpt.calibration.dtype, np.integer) or np.any(values < 0):
        fail("calibration must hold non-negative integer spike counts")
    if not ckpt.reference_traversals:
        fail("checkpoint names no reference traversal")
