"""The backends' registry: the implementations that run a network's spike trains.

A :class:`BackendKind` says which network it runs, which exported file it needs (if any) and how it is opened
into a :class:`~vprsnn_export.network.runs.Backend`. :func:`choose_backend` resolves ``auto`` (the float network
for a checkpoint, the integer simulator for a fixed-point model) and refuses a mismatch; evaluate, simulate,
localize and conformance get their counts through it. Adding one: a function and a ``BACKENDS.register`` line.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from vprsnn_export.errors import InvalidValueError, ModelFileError
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.registry import Registry

if TYPE_CHECKING:  # the registry is read by --help, which imports no torch: the implementations load when opened
    import torch

    from vprsnn_export.network.runs import Backend

Network = Checkpoint | FixedPointModel
#: open(network, exported file or None, device, threads, progress) -> a backend running that network
#: (``progress``: a bar on stderr over a long run, where the backend draws one)
OpenFunction = Callable[[Network, "Path | None", Any, "int | None", bool], "Backend"]


@dataclass(frozen=True)
class BackendKind:
    """One implementation: ``runs`` the network type it takes, ``needs`` the option naming the exported file it
    runs (None: the network alone), ``open`` builds it, ``description`` its help text."""

    name: str
    runs: type
    open: OpenFunction
    description: str
    needs: str | None = None
    tags: frozenset[str] = frozenset()  # what it is: FLOAT, EXACT (the model's integers, bit for bit), SLOW, FILE


def _float(network: Network, path: Path | None, device: torch.device, threads: int | None, progress: bool) -> Backend:
    from vprsnn_export.network.dynamics import FloatNetwork

    assert isinstance(network, Checkpoint)
    opened = FloatNetwork.from_arrays(network.weights, network.thresholds, network.config, device)
    opened.progress = progress
    return opened


def _integer(network: Network, path: Path | None, device: torch.device, threads: int | None, progress: bool) -> Backend:
    from vprsnn_export.targets.intsim import IntegerNetwork

    assert isinstance(network, FixedPointModel)
    return IntegerNetwork(network, device, progress=progress)


def _onnx(network: Network, path: Path | None, device: torch.device, threads: int | None, progress: bool) -> Backend:
    """One session on the graph; ModelFileError unless it was exported from ``network`` (its source and bit width)."""
    from vprsnn_export.targets.onnx_session import SessionBackend, read_onnx, session

    assert isinstance(network, FixedPointModel) and path is not None
    props = {p.key: p.value for p in read_onnx(path).metadata_props}
    if props.get("vprsnn.source_sha256") != network.source_sha256 or props.get("vprsnn.bits") != str(network.bits):
        raise ModelFileError(
            f"this graph was not exported from the given model (graph: source {props.get('vprsnn.source_sha256')}, "
            f"{props.get('vprsnn.bits')} bits; model: source {network.source_sha256}, {network.bits} bits)",
            path,
        )
    return SessionBackend(session(path, threads))


def _stepper(network: Network, path: Path | None, device: torch.device, threads: int | None, progress: bool) -> Backend:
    from vprsnn_export.targets.reference_stepper import ReferenceStepper

    assert isinstance(network, FixedPointModel)
    return ReferenceStepper(network)


#: The tags of a backend kind: the float network; an exact implementation of the fixed-point model (its
#: integers bit for bit: the conformance checks compare every such backend with the baseline); the baseline
#: the others are compared with; one too slow for more than a few presentations; one that runs an exported file.
FLOAT, EXACT, BASELINE, SLOW, FILE = "float", "exact integer", "baseline", "slow", "file"

BACKENDS: Registry[BackendKind] = Registry("--backend")
for name, runs, opener, description, needs, tags in (
    ("float", Checkpoint, _float, "the float network (a checkpoint)", None, {FLOAT}),
    ("integer", FixedPointModel, _integer, "the integer simulator (a fixed-point model)", None, {EXACT, BASELINE}),
    (
        "reference",
        FixedPointModel,
        _stepper,
        "the reference stepper: the slow oracle, one step at a time",
        None,
        {EXACT, SLOW},
    ),
    ("onnx", FixedPointModel, _onnx, "the graph exported from the model", "--onnx", {EXACT, FILE}),
):
    BACKENDS.register(BackendKind(name, runs, opener, description, needs, frozenset(tags)))


def tagged(*tags: str) -> tuple[BackendKind, ...]:
    return tuple(kind for kind in BACKENDS.values() if set(tags) <= kind.tags)


_NETWORKS = {Checkpoint: "a float checkpoint", FixedPointModel: "a fixed-point model (vprsnn-export quantize)"}


def choose_backend(network: Network, name: str = "auto", path: str | Path | None = None) -> BackendKind:
    """The kind named (``auto``: the first registered one that runs this network and needs a file exactly when
    one is given); InvalidValueError when it does not run this network or lacks its file."""
    if name == "auto":
        fits = [kind for kind in BACKENDS.values() if (kind.needs is None) == (path is None) and SLOW not in kind.tags]
        name = next((k for k in fits if isinstance(network, k.runs)), fits[0] if fits else BACKENDS.values()[0]).name
    kind = BACKENDS.get(name)
    needs = None if isinstance(network, kind.runs) else _NETWORKS.get(kind.runs, kind.runs.__name__)
    if needs is None and kind.needs is not None and path is None:
        needs = f"{kind.needs}: the file exported from this model"
    if needs is not None:
        raise InvalidValueError(f"--backend {name} needs {needs}")
    return kind


def open_backend(
    network: Network,
    name: str = "auto",
    path: str | Path | None = None,
    device: torch.device | None = None,
    threads: int | None = None,
    *,
    progress: bool = False,
) -> tuple[str, Backend]:
    """(the kind's name, the backend) of :func:`choose_backend`, opened on ``device`` (default CPU), with a
    progress bar over long runs when ``progress``."""
    import torch

    kind = choose_backend(network, name, path)
    opened = kind.open(network, None if path is None else Path(path), device or torch.device("cpu"), threads, progress)
    return kind.name, opened
