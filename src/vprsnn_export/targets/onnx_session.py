"""An exported ONNX graph read back, checked and run on onnxruntime (CPU): :class:`OnnxBackend`."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import torch

from vprsnn_export.errors import InvalidValueError, ModelFileError
from vprsnn_export.network.runs import SpikeRun
from vprsnn_export.targets.onnx_target import INPUT, MODULES
from vprsnn_export.targets.registry import load_file


@dataclass
class OnnxRun:
    """What one onnxruntime call returned, in the project's layout (presentations first)."""

    counts: np.ndarray  # (N, neurons) int64
    saturations: np.ndarray  # (N,) int64
    wprob: np.ndarray | None  # (N, places) float64
    raster: np.ndarray | None  # (N, T, neurons) bool


def checked_onnx(path: Path) -> onnx.ModelProto:
    loaded = onnx.load(str(path))
    onnx.checker.check_model(loaded)
    return loaded


def read_onnx(path: str | Path) -> onnx.ModelProto:
    """Load and check an exported graph; a missing, truncated or foreign file is a ModelFileError."""
    path = Path(path)
    loaded = load_file(path, "ONNX", "ONNX model", checked_onnx)  # onnx raises DecodeError, ValidationError...
    props = {p.key: p.value for p in loaded.metadata_props}
    if props.get("vprsnn.format") != "vprsnn-onnx/1":
        raise ModelFileError("not an ONNX graph written by vprsnn-export (metadata vprsnn.format missing)", path)
    check_interface(loaded, path)
    return loaded


#: The operators the project's ONNX writer uses (targets/onnx_target.py); a graph with any other is not one of its
#: files (an edited or foreign graph could loop or allocate without bound).
WRITER_OPS = frozenset(
    "Add And ArgMax BitShift BitwiseAnd Cast Clip Concat ConstantOfShape Div Equal Greater Identity MatMul "
    "MatMulInteger Mul Not Pad Range ReduceMax ReduceMin ReduceSum Reshape Scan ScatterND Shape Slice Sub Where".split()
)
REQUIRED_OUTPUTS = ("counts", "saturations")


def check_interface(loaded, path: Path) -> None:
    """ModelFileError unless the graph has the writer's interface: the input ``spikes`` [T, batch, inputs] with T
    and inputs fixed, then ``modules`` (the modules run, with a default; files written before the search window lack
    it), the outputs counts and saturations, and only :data:`WRITER_OPS`."""
    inputs = list(loaded.graph.input)
    shape = inputs[0].type.tensor_type.shape.dim if inputs else []
    dims = [d.dim_value if d.HasField("dim_value") else None for d in shape]
    if [i.name for i in inputs] not in ([INPUT], [INPUT, MODULES]) or len(dims) != 3 or not (dims[0] and dims[2]):
        raise ModelFileError(f"the graph's input is not {INPUT} [T, batch, inputs] with T and inputs fixed", path)
    if missing := [name for name in REQUIRED_OUTPUTS if name not in {o.name for o in loaded.graph.output}]:
        raise ModelFileError(f"the graph has no output {', '.join(missing)}: not a file export wrote", path)
    ops: set[str] = set()
    pending = [loaded.graph]
    while pending:  # every node's operator, and those of its subgraphs (a Scan's body)
        for node in pending.pop().node:
            ops.add(node.op_type)
            pending.extend(a.g for a in node.attribute if a.HasField("g"))
            pending.extend(g for a in node.attribute for g in a.graphs)
    if foreign := sorted(ops - WRITER_OPS):
        raise ModelFileError(f"the graph uses operators export never writes ({', '.join(foreign[:5])})", path)


def session(path: str | Path, threads: int | None = None):
    """An onnxruntime CPU session on a checked file."""
    import onnxruntime as ort

    loaded = read_onnx(path)
    options = ort.SessionOptions()
    options.log_severity_level = 3  # not the warning that the modules input (a default, fed to override) is no constant
    if threads is not None:
        options.intra_op_num_threads = threads
    try:
        return ort.InferenceSession(loaded.SerializeToString(), options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime's own Fail / InvalidGraph
        raise ModelFileError(f"onnxruntime cannot load this graph ({exc})", path) from None


def run_session(
    sess, spikes: torch.Tensor | np.ndarray, batch: int = 128, modules: tuple[int, int] | None = None
) -> OnnxRun:
    """Feed spikes (N, T, inputs) uint8 in chunks of ``batch`` presentations as [T, batch, inputs], with
    ``modules`` [first, last) run alone (None: the graph's default, every module).

    InvalidValueError when T or inputs differ from the graph's fixed input shape (:func:`session` opens only a
    graph whose T and inputs are fixed)."""
    array = np.asarray(spikes.numpy() if isinstance(spikes, torch.Tensor) else spikes)
    if array.ndim != 3 or array.dtype not in (np.uint8, np.bool_):
        raise InvalidValueError(f"expected spikes (N, T, inputs) of uint8, got {array.shape} {array.dtype}")
    timesteps, _, inputs = sess.get_inputs()[0].shape
    if (array.shape[1], array.shape[2]) != (timesteps, inputs):
        raise InvalidValueError(
            f"expected spikes (N, T, inputs) = (N, {timesteps}, {inputs}) for this graph, got {array.shape}"
        )
    chunks = (array[start : start + batch].astype(np.uint8).transpose(1, 0, 2) for start in range(0, len(array), batch))
    window = {} if modules is None else {MODULES: np.asarray(modules, dtype=np.int64)}
    runs = [sess.run(None, {INPUT: np.ascontiguousarray(chunk), **window}) for chunk in chunks]  # every output
    outputs = zip((o.name for o in sess.get_outputs()), *runs, strict=True)
    joined = {name: np.concatenate(parts, axis=1 if name == "raster" else 0) for name, *parts in outputs if parts}
    raster = None if "raster" not in joined else joined["raster"].transpose(1, 0, 2)  # (N, T, neurons)
    return OnnxRun(joined["counts"], joined["saturations"], joined.get("wprob"), raster)


def run_onnx_outputs(
    path: str | Path, spikes: torch.Tensor | np.ndarray, *, batch: int = 128, threads: int | None = None
) -> OnnxRun:
    """Every output of an exported graph for spikes (N, T, inputs)."""
    return run_session(session(path, threads), spikes, batch)


def run_onnx(path: str | Path, spikes: torch.Tensor | np.ndarray) -> np.ndarray:
    """Output spike counts (N, neurons) int64 of an exported graph on onnxruntime (CPU)."""
    return run_onnx_outputs(path, spikes).counts


@dataclass
class SessionBackend:
    """An ONNX graph in one onnxruntime session, opened once (a stream runs it frame by frame), as a
    :class:`~vprsnn_export.network.runs.Backend`; its runs carry the W+Prob distribution and the raster when the
    graph has those outputs (``record`` cannot add an output the graph lacks). ``modules`` [first, last): run those
    alone, their counts and raster (None: every module)."""

    session: Any  # an onnxruntime.InferenceSession
    batch: int = 128
    name: str = "onnxruntime"
    modules: tuple[int, int] | None = None

    def run(self, spikes: torch.Tensor, *, record: bool = False) -> SpikeRun:
        out = run_session(self.session, spikes, self.batch, self.modules)
        return SpikeRun(
            counts=torch.from_numpy(np.asarray(out.counts, dtype=np.int64)),
            raster=None if out.raster is None else torch.from_numpy(out.raster.astype(bool)),
            saturations=int(out.saturations.sum()),
            wprob=out.wprob,
        )


@dataclass
class OnnxBackend:
    """An exported graph on onnxruntime, opened for each run (:class:`SessionBackend`)."""

    path: Path
    threads: int | None = None
    batch: int = 128
    name: str = "onnxruntime"

    def run(self, spikes: torch.Tensor, *, record: bool = False) -> SpikeRun:
        return SessionBackend(session(self.path, self.threads), self.batch, self.name).run(spikes)
