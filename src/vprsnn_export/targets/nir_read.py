"""A NIR file read back (:func:`read_nir`): the checkpoint or fixed-point model :mod:`.nir_target` wrote.

Weights and thresholds come from the graph's nodes, the rest from its metadata; every
missing or inconsistent piece is a ModelFileError naming the file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vprsnn_export.errors import ModelFileError
from vprsnn_export.export.model import MODEL_ARRAYS, FixedPointModel, model_from_header
from vprsnn_export.io.checkpoint import FORMAT as CHECKPOINT_FORMAT
from vprsnn_export.io.checkpoint import Checkpoint, check_header, validate_checkpoint
from vprsnn_export.io.fileio import parse_json
from vprsnn_export.targets.nir_target import EDGES, FORMAT, FORMAT_VERSION, NODES, PLAIN_EDGES, Source, effective_beta
from vprsnn_export.targets.registry import load_file


def load_graph(path: str | Path):
    """``nir.read`` with every failure (h5py's OSError, nir's KeyError, ValueError...) a ModelFileError naming the file."""
    import nir

    return load_file(Path(path), "NIR", "NIR file", nir.read)


def read_nir(path: str | Path) -> Source:
    """Rebuild the exported network: a Checkpoint (float) or a FixedPointModel (fixed point) (module docstring)."""
    import nir

    path = Path(path)
    graph = load_graph(path)
    try:
        meta = graph.metadata
        if meta.get("format") != FORMAT:
            raise ModelFileError(f"not a vprsnn NIR export (metadata format {meta.get('format')!r})", path)
        if int(meta.get("format_version", -1)) != FORMAT_VERSION:
            raise ModelFileError(f"unsupported vprsnn NIR format version {meta.get('format_version')!r}", path)
        missing = [name for name in NODES if name not in graph.nodes and name != "wta"]
        if missing or sorted(map(tuple, graph.edges)) != sorted(EDGES if "wta" in graph.nodes else PLAIN_EDGES):
            raise ModelFileError(
                f"the graph is not the exported network (nodes missing: {missing}; edges {graph.edges})", path
            )
        linear, lif = graph.nodes["linear"], graph.nodes["lif"]
        if not isinstance(linear, nir.Linear) or not isinstance(lif, (nir.LIF, nir.IF)):
            raise ModelFileError("node 'linear' must be a Linear and 'lif' a LIF or IF", path)
        header = parse_json(str(meta["header_json"]), "header_json")
        rebuild = fixed_point_from_graph if str(meta["kind"]) == "fixed-point" else checkpoint_from_graph
        source = rebuild(header, meta, np.asarray(linear.weight).T, np.asarray(lif.v_threshold), path)
        check_dynamics(lif, effective_beta(source), float(meta["dt"]), path)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:  # a ModelFileError passes as it is
        raise ModelFileError(f"not a vprsnn NIR export ({type(exc).__name__}: {exc})", path) from None
    return source


def check_dynamics(lif, beta: float, dt: float, path: Path) -> None:
    """The node's tau and r must be the ones this beta and dt give (so node and metadata agree)."""
    import nir

    if isinstance(lif, nir.IF):
        if beta < 1.0:
            raise ModelFileError(f"an IF node but beta = {beta} < 1 in the metadata", path)
        return
    expect_tau, expect_r = dt / (1.0 - beta), 1.0 / (1.0 - beta)
    if not (np.allclose(lif.tau, expect_tau, rtol=1e-9) and np.allclose(lif.r, expect_r, rtol=1e-9)):
        raise ModelFileError(f"the LIF node's tau/r disagree with beta = {beta} and dt = {dt} in the metadata", path)
    if np.any(np.asarray(lif.v_reset) != 0) or np.any(np.asarray(lif.v_leak) != 0):
        raise ModelFileError("the LIF node must have v_reset = 0 and v_leak = 0", path)


def integral(array: np.ndarray, name: str, path: Path) -> np.ndarray:
    if not np.all(np.isfinite(array)) or np.any(array != np.round(array)):
        raise ModelFileError(f"{name} must hold integers in a fixed-point export", path)
    return np.round(array).astype(np.int32)


def fixed_point_from_graph(
    header: dict, meta: dict, weight: np.ndarray, thresholds: np.ndarray, path: Path
) -> FixedPointModel:
    """The fixed-point model of a NIR file: its embedded header and the graph's integer weights and thresholds."""
    arrays = {
        "weight_mantissa": integral(weight, "linear.weight", path),
        "scale_multiplier": np.asarray(meta["wta_score_multiplier"]).astype(np.int32),
        "threshold": integral(thresholds, "lif.v_threshold", path),
        **{name: np.asarray(meta[name]).astype(np.int64) for name in MODEL_ARRAYS[3:]},
    }
    return model_from_header(header, arrays, path, "NIR fixed-point header")


def checkpoint_from_graph(
    header: dict, meta: dict, weight: np.ndarray, thresholds: np.ndarray, path: Path
) -> Checkpoint:
    if header.get("format") != CHECKPOINT_FORMAT:
        raise ModelFileError(f"the embedded header is not a checkpoint header ({header.get('format')!r})", path)
    config, traversals, data, history = check_header(header, path)  # the checkpoint reader's own checks
    calibration, ids = (np.asarray(meta[name]).astype(np.int64) for name in ("calibration", "reference_place_ids"))
    weights = np.ascontiguousarray(weight.astype(np.float32))
    version = str(header.get("package_version", "unknown"))
    ckpt = Checkpoint(
        config, weights, thresholds.astype(np.float32), calibration, ids, traversals, data, history, version
    )
    validate_checkpoint(ckpt, path)
    return ckpt
