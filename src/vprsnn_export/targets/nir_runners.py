"""A NIR file run by float consumers that ignore its metadata, and how their rasters compare.

:func:`generic_consumer_raster` steps NIR's own LIF equations through nirtorch; the snnTorch,
Norse and SpikingJelly runners load the file with each importer (Norse and SpikingJelly with the
file's ``consumer_settings``, :func:`consumer_graph`); :data:`CONSUMERS` names them and
:func:`spike_agreement` measures a raster against the network's.
"""

from __future__ import annotations

import contextlib
import copy
import importlib
import io
import logging
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.targets.nir_target import DT_SECONDS


class EulerLIF(torch.nn.Module):
    """NIR's LIF (or IF) as written in the file, stepped by forward Euler at ``dt``: no metadata used.

    v <- v + dt/tau ((v_leak - v) + r I)      (IF, dv/dt = r I: v <- v + (dt r) I)
    z = v > v_threshold;  v <- v_reset where z
    """

    def __init__(self, node, dt: float) -> None:
        import nir

        super().__init__()
        n = np.asarray(node.v_threshold).shape
        leaky = isinstance(node, nir.LIF)
        gain = dt / np.asarray(node.tau, dtype=np.float64) if leaky else np.zeros(n)
        drive = (gain if leaky else dt) * np.asarray(node.r, dtype=np.float64)
        v_leak = getattr(node, "v_leak", np.zeros(n))
        for name, value in (("gain", gain), ("drive", drive), ("v_leak", v_leak), ("v_threshold", node.v_threshold)):
            self.register_buffer(name, torch.as_tensor(np.asarray(value, dtype=np.float64)))
        self.register_buffer("v_reset", torch.as_tensor(np.asarray(node.v_reset, dtype=np.float64)))

    gain: torch.Tensor
    drive: torch.Tensor
    v_leak: torch.Tensor
    v_threshold: torch.Tensor
    v_reset: torch.Tensor

    def forward(self, x: torch.Tensor, state: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        v = torch.zeros_like(x) if state is None else state
        v = v + self.gain * (self.v_leak - v) + self.drive * x
        z = v > self.v_threshold
        return z.to(x.dtype), torch.where(z, self.v_reset, v)


def generic_consumer_raster(graph, spikes: torch.Tensor, *, dt: float = DT_SECONDS) -> torch.Tensor:
    """Run a NIR graph through nirtorch's generic interpreter with NIR's own LIF equations.

    This is what a consumer that reads only the nodes (no metadata) computes: float32,
    forward Euler at ``dt``, every neuron over threshold spikes. Returns (N, T, neurons) bool.
    """
    import nir
    import nirtorch

    node_map = {nir.LIF: lambda node: EulerLIF(node, dt), nir.IF: lambda node: EulerLIF(node, dt)}
    return step_module(nirtorch.nir_to_torch(graph, node_map), spikes)


def step_module(module, spikes: torch.Tensor, read: Callable[..., torch.Tensor] = lambda z, _: z) -> torch.Tensor:
    """Feed (N, T, inputs) one step at a time to a stateful torch module returning (z, state); the raster
    (N, T, neurons) bool of ``read(z, state)`` (default: z)."""
    state = None
    outputs = []
    with torch.no_grad():
        for t in range(spikes.shape[1]):
            z, state = module(spikes[:, t].to(torch.float32), state)
            outputs.append(read(z, state).detach().to(torch.bool))
    return torch.stack(outputs, dim=1)


def snntorch_consumer_raster(graph, spikes: torch.Tensor) -> torch.Tensor:
    """Run a NIR graph through snnTorch's importer (``snntorch.import_from_nir``), stepped per t.

    snnTorch's importer asserts one threshold for all neurons; it raises for files with
    per-neuron thresholds (quantise with threshold folding to get a single threshold).
    """
    from snntorch.import_nir import import_from_nir

    with contextlib.redirect_stdout(io.StringIO()):
        module = import_from_nir(copy.deepcopy(graph))
    return step_module(module, spikes)


CONSUMERS_INSTALL = 'pip install -c constraints.txt ".[consumers]"'


def consumer_package(module: str, label: str) -> Any:
    """The consumer's ``module`` imported; InvalidValueError saying what to install when its package is missing."""
    try:
        return importlib.import_module(module)
    except ImportError:
        package = module.split(".")[0]
        raise InvalidValueError(f"the {label} consumer needs the {package} package ({CONSUMERS_INSTALL})") from None


def consumer_graph(graph, consumer: str, dt: float = DT_SECONDS):
    """A copy of ``graph`` with :func:`consumer_settings` applied for ``consumer`` (norse, spikingjelly).

    norse (LIF):   v_threshold'_j = g_j v_threshold_j,  g_j = dt * (1 / tau_j)   (all float32, Norse's order)
    spikingjelly:  v_threshold'_j = nextafter(float32(v_threshold_j), +inf)
    """
    import nir

    adjusted = copy.deepcopy(graph)
    lif = adjusted.nodes["lif"]
    threshold32 = torch.as_tensor(np.asarray(lif.v_threshold), dtype=torch.float32)
    if consumer != "norse":
        lif.v_threshold = np.nextafter(threshold32.numpy(), np.float32(np.inf)).astype(np.float64)
    elif isinstance(lif, nir.LIF):  # an IF node (no tau) keeps its threshold
        gain = dt * (1 / torch.as_tensor(np.asarray(lif.tau), dtype=torch.float32))
        lif.v_threshold = (gain * threshold32).numpy().astype(np.float64)
    return adjusted


def norse_consumer_raster(graph, spikes: torch.Tensor, *, dt: float = DT_SECONDS, plain: bool = False) -> torch.Tensor:
    """Run a NIR graph through Norse's importer (``norse.torch.from_nir``, an optional package) at ``dt``.

    Norse 1.1 ignores the LIF's r (it integrates v <- v + dt/tau (v_leak - v + I)); unless
    ``plain``, the thresholds are scaled by dt/tau first as :func:`consumer_settings` says. Its graph
    executor returns the output of the last node it runs, which is ``wta`` when that node is
    present, so the spikes are read from the executor's cache of the ``lif`` node instead.
    """
    norse_torch = consumer_package("norse.torch", "Norse")
    logging.getLogger().disabled = True
    try:
        module = norse_torch.from_nir(graph if plain else consumer_graph(graph, "norse", dt), dt=dt)
    finally:
        logging.getLogger().disabled = False
    return step_module(module, spikes, lambda _, state: state.cache["lif"])


def spikingjelly_consumer_raster(graph, spikes: torch.Tensor, *, plain: bool = False) -> torch.Tensor:
    """Run a NIR graph through SpikingJelly's importer (``nir_exchange.import_from_nir``, optional) at DT_SECONDS.

    SpikingJelly 2.0 maps the LIF (r = tau/dt) to ``LIFNode(tau/dt, decay_input=False)``:
    v <- v - v dt/tau + I = beta v + I, and fires at v >= v_threshold; unless ``plain``, the
    threshold is moved to the next float32 above it as :func:`consumer_settings` says. It
    refuses (ValueError) per-neuron thresholds.
    """
    nir_exchange = consumer_package("spikingjelly.activation_based.nir_exchange", "SpikingJelly")
    consumer_package("spikingjelly.logger", "SpikingJelly").logger.disable("spikingjelly")
    module = nir_exchange.import_from_nir(graph if plain else consumer_graph(graph, "spikingjelly"), dt=DT_SECONDS)
    return step_module(module, spikes)


CONSUMERS = {
    "nirtorch": generic_consumer_raster,
    "snntorch": snntorch_consumer_raster,
    "norse": norse_consumer_raster,
    "norse-plain": lambda graph, spikes: norse_consumer_raster(graph, spikes, plain=True),
    "spikingjelly": spikingjelly_consumer_raster,
    "spikingjelly-plain": lambda graph, spikes: spikingjelly_consumer_raster(graph, spikes, plain=True),
}


def spike_agreement(reference: torch.Tensor, consumer: torch.Tensor) -> dict[str, float]:
    """How a consumer's raster (N, T, neurons) relates to the network's.

    recall: share of the network's spikes the consumer also emits; precision: share of the
    consumer's spikes that are the network's; exact_steps: share of (presentation, step)
    with identical spike vectors; top1: share of presentations whose most-spiking neuron
    (argmax of counts, lowest index on ties) is the same.
    """
    ref, out = reference.to(torch.bool), consumer.to(torch.bool)
    both = int((ref & out).sum())
    n_ref, n_out = int(ref.sum()), int(out.sum())
    return {
        "recall": both / n_ref if n_ref else 1.0,
        "precision": both / n_out if n_out else 1.0,
        "exact_steps": float((ref == out).all(dim=2).float().mean()),
        "top1_neuron": float((ref.sum(dim=1).argmax(dim=1) == out.sum(dim=1).argmax(dim=1)).float().mean()),
        "network_spikes": n_ref,
        "consumer_spikes": n_out,
    }
