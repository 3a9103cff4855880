"""The NIR consumer gate: the field's float consumers must decide as the network does, within a stated tolerance.

``export --check`` and ``verify --targets nir`` run every installed float NIR consumer
(:data:`~vprsnn_export.targets.nir_consumers.GATE_CONSUMERS`), apply the file's readout rule to its WTA-off raster
and compare decisions:

    agreement = mean over queries of [ place(consumer + rule) == place(network) ]
    passes when agreement >= tolerance

where place is the W+Prob decision (k = 1) with the network's own calibration, and the tolerance is the file's
``float_consumers.decision_tolerance`` unless the caller gives one. Each consumer gives one
:class:`~vprsnn_export.runtime.results.Comparison`, which fails the export or verification like any other check.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.readout.strategies import SEQUENCE_STRATEGY, decide
from vprsnn_export.targets.nir_consumers import GATE_CONSUMERS, ConsumerUnavailable, available, run_consumer
from vprsnn_export.targets.nir_read import load_graph
from vprsnn_export.targets.nir_semantics import float_consumers
from vprsnn_export.targets.nir_target import apply_readout_rule
from vprsnn_export.targets.registry import TARGETS

from .conformance import wprob_readout
from .results import Comparison, ConformanceResult


def decided_places(network: Checkpoint | FixedPointModel, counts: np.ndarray) -> np.ndarray:
    """The sequence strategy's (W+Prob) decision (k = 1) of each presentation with the network's own
    calibration (an ensemble's with its region regularisation)."""
    return decide(wprob_readout(network)(counts), SEQUENCE_STRATEGY)[0]


def check_tolerance(tolerance: float | None) -> float | None:
    if tolerance is not None and not 0.0 <= tolerance <= 1.0:
        raise InvalidValueError(f"the NIR consumer tolerance must be a fraction in [0, 1], got {tolerance}")
    return tolerance


def consumer_gate(
    path: str | Path,
    network: Checkpoint | FixedPointModel,
    raster: torch.Tensor,
    spikes: torch.Tensor,
    *,
    tolerance: float | None = None,
    label: str = TARGETS.get("nir").label,
) -> tuple[Comparison, ...]:
    """One comparison per installed consumer: decisions of consumer + readout rule vs the network's.

    ``raster``: the network's raster (N, T, neurons) of ``spikes``, with its own WTA setting. A consumer that
    refuses the file gives a passing row saying so; a graph with the recurrent ``wta`` node is not gated.
    ``label``: the file's target's label (its rows land under that target).
    """
    graph = load_graph(path)
    if "wta" in graph.nodes:
        return ()
    statement = float_consumers(network)
    limit = float(statement["decision_tolerance"]) if check_tolerance(tolerance) is None else tolerance
    truth = raster.to(torch.bool)
    places = decided_places(network, truth.sum(dim=1).numpy())
    rows: list[Comparison] = []
    kind = f"decision agreement >= {limit:.1%}"
    for consumer in filter(available, GATE_CONSUMERS):
        check = f"{label}: {consumer} + readout rule"
        try:
            candidates = run_consumer(consumer, graph, spikes)
        except (AssertionError, ValueError, ConsumerUnavailable) as exc:  # snnTorch asserts, SpikingJelly raises
            detail = f"not gated: the consumer refuses the file ({type(exc).__name__}: {str(exc).splitlines()[0]})"
            rows.append(Comparison(check, consumer, "network", kind, False, detail, tolerance=limit))
            continue
        ruled = apply_readout_rule(graph, spikes, candidates)
        agree = decided_places(network, ruled.sum(dim=1).numpy()) == places
        share = float(agree.mean()) if agree.size else 1.0
        differing = int((ruled != truth).sum())
        detail = (
            f"{share:.1%} of {agree.size} decisions agree (tolerance {limit:.1%}); {differing} of {truth.numel()} "
            f"raster entries differ after the rule; file mode {statement['mode']}, "
            + ("stated exact" if statement["exact"] else f"not exact: {statement['cause']}")
        )
        identical = bool(agree.all() and differing == 0)  # a tolerance row is never counted as exact
        counted = int((~agree).sum()), int(agree.size)
        rows.append(Comparison(check, consumer, "network", kind, identical, detail, *counted, tolerance=limit))
    return tuple(rows)


def with_consumer_gate(
    result: ConformanceResult, model: FixedPointModel, raster: torch.Tensor | None, spikes: torch.Tensor
) -> ConformanceResult:
    """``result`` (a verification's cross-implementation checks) plus the gate on each written file that the field's
    float consumers read (:attr:`~vprsnn_export.targets.registry.Target.float_consumers`: NIR)."""
    gated = [(TARGETS.get(name), files[0]) for name, files in result.files.items() if name in TARGETS and files]
    gate = tuple(
        row
        for entry, path in gated
        if entry.float_consumers and raster is not None
        for row in consumer_gate(path, model, raster, spikes, label=entry.label)
    )
    return dataclasses.replace(result, comparisons=result.comparisons + gate)
