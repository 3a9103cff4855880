"""An ensemble trained, calibrated and run on a cluster: tasks of modules, gathered into one network.

Module m's training depends on its own rows and the config alone (:mod:`.batched`), and its
spikes on its own weights, thresholds and the input spikes (the WTA acts within a module). So
a task trains or runs a contiguous group of modules [a, b) anywhere, and the driver gathers

    weights    = [W_a | ... | W_b-1]  side by side, in module order      (inputs, M n)
    thresholds = [theta_a, ..., theta_b-1]                               (M n,)
    history    = history_entry over the gathered per-epoch fired and theta (as train_modules)
    counts     = [c_a | ... | c_b-1]  side by side                        (N, M n)
    |C[t]|     = sum over groups of each group's candidates per step     (N, T)

which is what one process computes, bit for bit (tests/trainer/test_sharded.py). Each task
receives the images of its rows (training) or the images of every presentation (counting) and
encodes them itself with the seeded encoder, so workers need no data path.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from scipy import sparse

from vprsnn_export.cluster import Cluster, map_tasks
from vprsnn_export.config import Config, wta_group
from vprsnn_export.data.encoding import calibration_spikes, query_spikes
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.network.dynamics import FloatNetwork

from .batched import module_epochs, side_by_side
from .calibrate import DENSE_COUNT_ENTRIES, calibration_chunk, calibration_matrix
from .train import Presentation, TrainedNetwork, history_entry, initial_state

STREAMS = {"query": query_spikes, "calibrate": calibration_spikes}
CPU = torch.device("cpu")


@dataclass(frozen=True)
class GroupTraining:
    """One task's modules after training: final weights and every epoch's fired and theta."""

    weights: np.ndarray  # (modules, inputs, n) float32
    fired: np.ndarray  # (epochs, modules, n) float32
    theta: np.ndarray  # (epochs, modules, n) float32
    seconds: np.ndarray  # (epochs,) wall time of each epoch on the worker


def module_groups(n_modules: int, modules_per_task: int) -> list[range]:
    """Contiguous groups [a, a + k) of modules, one per task (the last may be shorter)."""
    step = max(1, int(modules_per_task))
    return [range(a, min(a + step, n_modules)) for a in range(0, n_modules, step)]


def group_inputs(
    images: np.ndarray, presentations: Sequence[Presentation], rows: Sequence[np.ndarray]
) -> tuple[np.ndarray, list[Presentation], list[np.ndarray]]:
    """The images and presentations a group of modules trains on, with its rows renumbered into them."""
    used = np.unique(np.concatenate(rows))
    return images[used], [presentations[int(r)] for r in used], [np.searchsorted(used, r) for r in rows]


def train_group(
    images: np.ndarray, presentations: Sequence[Presentation], rows: Sequence[np.ndarray], cfg: Config
) -> GroupTraining:
    """A task: train a group of modules on the CPU (module m on ``images[rows[m]]``), keeping each epoch's state."""
    weights = initial_state(cfg, len(rows), CPU)[0]
    kept: list[tuple[np.ndarray, np.ndarray, float]] = []  # each epoch's fired and theta (its own), not its weights
    for state in module_epochs(images, presentations, rows, cfg, device=CPU):
        weights = state.weights
        kept.append((state.fired.numpy(), state.theta.numpy(), state.seconds))
    shape = (len(kept), len(rows), cfg.network.n_neurons)
    fired, theta = (np.array([epoch[k] for epoch in kept], np.float32).reshape(shape) for k in (0, 1))
    return GroupTraining(weights.numpy().copy(), fired, theta, np.array([e[2] for e in kept], dtype=np.float64))


def train_modules_on_cluster(
    images: np.ndarray,
    presentations: Sequence[Presentation],
    rows: Sequence[np.ndarray],
    cfg: Config,
    cluster: Cluster | None,
    *,
    modules_per_task: int = 1,
    timing: list | None = None,
    progress: bool = False,
) -> TrainedNetwork:
    """:func:`.batched.train_modules` with its modules split into tasks on ``cluster`` (None: here, one by one).

    Same weights, thresholds and history (less wall-clock seconds: an epoch's is its slowest task's).
    ``timing``: the map's :class:`~vprsnn_export.cluster.TaskTiming` is appended.
    """
    if not rows or any(len(r) == 0 for r in rows):
        raise InvalidValueError("no training images for a module")
    groups = module_groups(len(rows), modules_per_task)
    tasks = [(*group_inputs(images, presentations, [rows[m] for m in group]), cfg) for group in groups]
    bar = "training modules" if progress else None
    done: list[GroupTraining] = map_tasks(cluster, train_group, tasks, timing=timing, progress=bar)
    weights = torch.from_numpy(np.concatenate([g.weights for g in done]))
    fired = np.concatenate([g.fired for g in done], axis=1)
    theta = np.concatenate([g.theta for g in done], axis=1)
    seconds = np.max([g.seconds for g in done], axis=0)  # (epochs,): each epoch's slowest task
    n_rows = np.array([len(r) for r in rows])
    history = [
        history_entry(e, float(seconds[e]), torch.from_numpy(fired[e]), torch.from_numpy(theta[e]), n_rows)
        for e in range(len(fired))
    ]
    final = torch.from_numpy(theta[-1]) if len(theta) else initial_state(cfg, len(rows), CPU)[1]
    return TrainedNetwork(side_by_side(weights), final.reshape(-1).contiguous(), history)


def run_group(
    weights: np.ndarray,
    thresholds: np.ndarray,
    cfg: Config,
    images: np.ndarray,
    place_ids: np.ndarray,
    traversal: str,
    stream: str,
) -> tuple[sparse.csr_array, np.ndarray]:
    """A task: encode the presentations and run a group of modules on them (float, CPU),
    :func:`.calibrate.calibration_chunk` of them at a time (each from its own seed and V = 0 when state-isolated,
    so the counts are those of all at once): (counts (N, neurons) int64 CSR, |C[t]| (N, T) int32)."""
    network = FloatNetwork.from_arrays(weights, thresholds, cfg, CPU)
    if len(place_ids) == 0:
        none = np.zeros((0, cfg.encoder.timesteps), dtype=np.int32)
        return sparse.csr_array((0, weights.shape[1]), dtype=np.int64), none
    chunk = calibration_chunk(cfg, len(place_ids))
    counts, candidates = [], []
    for start in range(0, len(place_ids), chunk):
        part = slice(start, start + chunk)
        run = network.run(STREAMS[stream](images[part], place_ids[part], traversal, cfg))
        assert run.candidates_per_step is not None  # the float network always reports them
        counts.append(sparse.csr_array(run.counts.numpy().astype(np.int64)))
        candidates.append(run.candidates_per_step.numpy())
    return sparse.vstack(counts, format="csr"), np.concatenate(candidates)


@dataclass(frozen=True)
class GatheredRun:
    """One traversal's presentations gathered from the tasks: counts (N, neurons) int64 CSR (with the hard WTA a
    presentation spikes at most T times per WTA group, so a 100,000-place route's counts under one WTA fit where a
    dense array would not) and |C[t]| (N, T) int32."""

    counts: sparse.csr_array
    candidates_per_step: np.ndarray


def float_runs_on_cluster(
    weights: np.ndarray,
    thresholds: np.ndarray,
    cfg: Config,
    presentations: Mapping[str, np.ndarray],
    place_ids: np.ndarray,
    stream: str,
    cluster: Cluster | None,
    *,
    modules_per_task: int = 1,
    progress: bool = False,
) -> dict[str, GatheredRun]:
    """The float ensemble on each traversal's images, split into tasks: one :class:`GatheredRun` per traversal.

    Counts and candidates per step equal ``FloatNetwork(weights, thresholds).run`` on the same
    spikes (``stream``: "query" or "calibrate" presentations). With one WTA per module
    (``network.wta_scope = module``) the modules run apart, a group of ``modules_per_task`` per task.
    With one WTA over the ensemble they compete at every step and cannot run apart, so the
    presentations are split instead (as many slices as module groups; one slice without state
    isolation, where each presentation starts from the previous one's voltage): every task runs the
    whole network on its slice, and each presentation's spikes are a pure function of its key.
    """
    n = cfg.network.n_neurons
    groups = module_groups(weights.shape[1] // n, modules_per_task)
    parts: list[tuple[np.ndarray, np.ndarray, slice | np.ndarray]]  # weights, thresholds, presentations of a task
    if wta_group(cfg, weights.shape[1]) == n or len(groups) == 1:
        columns = [slice(group.start * n, group.stop * n) for group in groups]
        every = slice(None)  # each task runs every presentation on its modules
        parts = [(np.ascontiguousarray(weights[:, c]), np.ascontiguousarray(thresholds[c]), every) for c in columns]
        axis = 1
    else:
        split = np.array_split(np.arange(len(place_ids)), len(groups) if cfg.network.state_isolation else 1)
        parts = [(weights, thresholds, piece) for piece in split if len(piece)]
        axis = 0
    tasks = [
        (w, t, cfg, images[rows], place_ids[rows], traversal, stream)
        for traversal, images in presentations.items()
        for w, t, rows in parts
    ]
    done = map_tasks(cluster, run_group, tasks, progress=f"{stream} runs" if progress else None)
    runs: dict[str, GatheredRun] = {}
    for k, traversal in enumerate(presentations):
        results = done[k * len(parts) : (k + 1) * len(parts)]
        counts = (sparse.hstack if axis == 1 else sparse.vstack)([c for c, _ in results], format="csr")
        steps = [c for _, c in results]  # |C[t]|: the module groups' add up, the presentation slices' follow on
        candidates = np.sum(steps, axis=0, dtype=np.int64) if axis == 1 else np.concatenate(steps)
        runs[traversal] = GatheredRun(counts, np.asarray(candidates, dtype=np.int32))
    return runs


def calibrate_on_cluster(
    weights: np.ndarray,
    thresholds: np.ndarray,
    cfg: Config,
    reference_images: Mapping[str, np.ndarray],
    place_ids: np.ndarray,
    cluster: Cluster | None,
    *,
    modules_per_task: int = 1,
    progress: bool = False,
    dense_entries: int = DENSE_COUNT_ENTRIES,
) -> np.ndarray | sparse.csr_array:
    """S^R = sum over reference traversals of counts^T, as :func:`.calibrate.calibrate` on the float network: dense
    int64 up to ``dense_entries`` entries, else CSR (the same integers)."""
    args = (weights, thresholds, cfg, reference_images, place_ids, "calibrate", cluster)
    runs = float_runs_on_cluster(*args, modules_per_task=modules_per_task, progress=progress)
    counts = [runs[traversal].counts.T.tocsr() for traversal in reference_images]
    return calibration_matrix(sum(counts[1:], counts[0]), dense_entries)
