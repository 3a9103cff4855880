"""What the field's float NIR consumers compute from a file: one runner per consumer, by name.

Each runner takes a ``nir.NIRGraph`` and input spikes (N, T, inputs) and returns the
consumer's WTA-off raster (N, T, neurons) bool, or raises (AssertionError, ValueError,
:class:`ConsumerUnavailable`) when the consumer refuses the file or is not installed.

``nir-spec-f32`` / ``nir-spec-f64`` are NIR's LIF written from the NIR specification as a
nirtorch user would write it, at the file's dt, in one float type throughout:

    I = W s[t];  v <- v + (dt / tau) ((v_leak - v) + r I)   (IF, dv/dt = r I: v <- v + (dt r) I)
    z = v > v_threshold;  v <- v_reset where z

The integer network's leak is V <- trunc(V (4096 - dv) / 4096) + a (rounding toward zero),
which no float LIF computes: the float voltage drifts from the integer one by up to
1 / (1 - beta) mantissa units, and a crossing moves whenever a voltage sits that close to the
threshold. With dv = 0 (beta = 1, an IF node) the update is v <- v + a on integers, which
float32 computes exactly while |v| < 2**24 (metadata ``float_consumers``).
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from vprsnn_export.errors import VprError
from vprsnn_export.targets.nir_runners import CONSUMERS, norse_consumer_raster

NORSE_DEFAULT_DT = 1e-3  # norse.torch.from_nir's default dt


class ConsumerUnavailable(VprError):
    """The consumer's package is not installed or cannot load NIR's LIF at all."""


def spec_lif_raster(graph, spikes: torch.Tensor, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """NIR's LIF/IF from the specification at the file's dt, every operation in ``dtype`` (module docstring)."""
    import nir

    lif = graph.nodes["lif"]

    def tensor(value: Any) -> torch.Tensor:
        return torch.as_tensor(np.asarray(value, dtype=np.float64), dtype=dtype)

    weight = tensor(graph.nodes["linear"].weight)
    threshold, v_reset, r = tensor(lif.v_threshold), tensor(lif.v_reset), tensor(lif.r)
    leaky = isinstance(lif, nir.LIF)
    dt = tensor(float(graph.metadata["dt"]))
    gain = dt / tensor(lif.tau) if leaky else None
    v_leak = tensor(lif.v_leak) if leaky else None
    drive = dt * r
    currents = spikes.to(dtype) @ weight.T  # (N, T, neurons)
    v = torch.zeros((spikes.shape[0], weight.shape[0]), dtype=dtype)
    out = torch.empty(currents.shape, dtype=torch.bool)
    for t in range(spikes.shape[1]):
        if gain is not None and v_leak is not None:
            v = v + gain * ((v_leak - v) + r * currents[:, t])
        else:
            v = v + drive * currents[:, t]
        z = v > threshold
        out[:, t] = z
        v = torch.where(z, v_reset, v)
    return out


def _installed(package: str) -> bool:
    return importlib.util.find_spec(package) is not None


def rockpool_raster(graph, spikes: torch.Tensor) -> torch.Tensor:
    """Rockpool 3.1 ``rockpool.nn.modules.from_nir``: measured to fail on ``nir.LIF`` (AttributeError: no
    ``tau_mem``) and on ``nir.IF`` (NotImplementedError); the failure is reported as the cause."""
    if not _installed("rockpool"):
        raise ConsumerUnavailable("rockpool is not installed")
    from rockpool.nn.modules import from_nir

    try:
        module = from_nir(graph)
    except Exception as exc:  # noqa: BLE001  a third-party importer's own failure is the measurement
        raise ConsumerUnavailable(f"rockpool from_nir fails: {type(exc).__name__}: {exc}") from None
    raise ConsumerUnavailable(f"rockpool loaded the file as {type(module).__name__}; no runner written for it")


def spyx_raster(graph, spikes: torch.Tensor) -> torch.Tensor:
    """Spyx 1.0 (JAX): spikes on the previous step's voltage, subtractive reset (field notes §8)."""
    if not _installed("spyx"):
        raise ConsumerUnavailable("spyx (JAX) is not installed")
    raise ConsumerUnavailable("spyx: fires on the previous step's voltage and resets by subtraction")


#: Matrix columns: name -> (runner, what it is). The last ones raise ConsumerUnavailable with the cause.
MATRIX_CONSUMERS: dict[str, tuple[Callable[[Any, torch.Tensor], torch.Tensor], str]] = {
    "nir-spec-f32": (lambda g, s: spec_lif_raster(g, s, torch.float32), "NIR's LIF from the spec, float32, file dt"),
    "nir-spec-f64": (lambda g, s: spec_lif_raster(g, s, torch.float64), "NIR's LIF from the spec, float64, file dt"),
    "eulerlif": (CONSUMERS["nirtorch"], "the project's EulerLIF through nirtorch.nir_to_torch (float32 buffers)"),
    "snntorch": (CONSUMERS["snntorch"], "snntorch.import_nir.import_from_nir"),
    "norse": (CONSUMERS["norse"], "Norse from_nir with the file's consumer_settings (dt 1e-4, gain threshold)"),
    "norse-default": (  # as a user loads the file without its settings: norse.torch.from_nir(graph)
        lambda g, s: norse_consumer_raster(g, s, dt=NORSE_DEFAULT_DT, plain=True),
        "Norse from_nir(graph) as is: dt 1e-3, r ignored",
    ),
    "spikingjelly": (CONSUMERS["spikingjelly"], "SpikingJelly with the file's consumer_settings"),
    "spikingjelly-default": (CONSUMERS["spikingjelly-plain"], "SpikingJelly import_from_nir(graph, dt=1e-4) as is"),
    "rockpool": (rockpool_raster, "Rockpool 3.1 from_nir"),
    "spyx": (spyx_raster, "Spyx 1.0"),
}

#: The consumers the export and verify gates run (those installed; refusals are reported, not failed).
GATE_CONSUMERS = ("nir-spec-f32", "nir-spec-f64", "eulerlif", "snntorch", "norse", "spikingjelly")
PACKAGES = {"eulerlif": "nirtorch", "snntorch": "snntorch", "norse": "norse", "spikingjelly": "spikingjelly"}


def available(consumer: str) -> bool:
    """Whether the consumer's package is importable (the spec LIFs need none)."""
    package = PACKAGES.get(consumer.removesuffix("-default"))
    return package is None or _installed(package)


def run_consumer(consumer: str, graph, spikes: torch.Tensor) -> torch.Tensor:
    """The WTA-off raster of ``consumer`` (:data:`MATRIX_CONSUMERS`); raises what it raises when it refuses the file."""
    if not available(consumer):
        raise ConsumerUnavailable(f"{PACKAGES[consumer.removesuffix('-default')]} is not installed")
    return MATRIX_CONSUMERS[consumer][0](graph, spikes)
