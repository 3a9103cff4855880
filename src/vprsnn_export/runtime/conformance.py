"""Cross-implementation conformance: every backend of one network must compute what the baseline computes.

The baseline is the integer simulator (a fixed-point model) or the float network (a checkpoint exported to NIR);
each *contender* (the reference stepper on the first presentations, ONNX on onnxruntime, the NIR and Loihi-style
files read back) runs on the same spike tensor. Every :class:`~vprsnn_export.network.runs.SpikeRun` field both
report is compared exactly; a W+Prob head must give identical decisions within ``WPROB_ROUNDING``; a model read
back from a file is compared with the one written, integer by integer. Used by `verify` and `export --check`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.network.runs import Backend, SpikeRun
from vprsnn_export.readout.scoring import Readout
from vprsnn_export.readout.strategies import SEQUENCE_STRATEGY, decide
from vprsnn_export.targets.onnx_target import WPROB_ROUNDING
from vprsnn_export.targets.registry import TARGETS, WriteOptions

from .backends import BASELINE, EXACT, SLOW, Network, open_backend, tagged
from .results import Comparison, ConformanceResult

#: The SpikeRun fields compared exactly (named in the check's label without "_per_step").
RUN_FIELDS = ("raster", "counts", "candidates_per_step", "final_voltage", "saturations")


def as_array(value: Any) -> np.ndarray:
    return value.detach().cpu().numpy() if isinstance(value, torch.Tensor) else np.asarray(value)


def exact_comparison(check: str, a_name: str, a: Any, b_name: str, b: Any) -> Comparison:
    """Bit-for-bit equality of two arrays (or integers): any difference fails."""
    a_arr, b_arr = as_array(a), as_array(b)
    if a_arr.shape != b_arr.shape:
        return Comparison(
            check, a_name, b_name, "exact", False, f"shapes differ: {a_arr.shape} vs {b_arr.shape}", None, a_arr.size
        )
    differ = a_arr != b_arr
    n_diff = int(np.count_nonzero(differ))
    if n_diff == 0:
        return Comparison(check, a_name, b_name, "exact", True, f"identical ({a_arr.size} values)", 0, a_arr.size)
    first = tuple(int(i) for i in np.unravel_index(int(np.flatnonzero(differ)[0]), differ.shape))
    detail = f"{n_diff} of {a_arr.size} values differ; first at {list(first)}: {a_arr[first]!r} vs {b_arr[first]!r}"
    return Comparison(check, a_name, b_name, "exact", False, detail, n_diff, int(a_arr.size), first)


def distribution_comparison(check: str, a_name: str, a: np.ndarray, b_name: str, b: np.ndarray) -> Comparison:
    """Two W+Prob distributions: identical decisions and max |a - b| <= ``WPROB_ROUNDING`` (float64 rounding)."""
    a_arr, b_arr = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    kind = f"decisions exact, |diff| <= {WPROB_ROUNDING:g}"
    if a_arr.shape != b_arr.shape:
        detail = f"shapes differ: {a_arr.shape} vs {b_arr.shape}"
        return Comparison(check, a_name, b_name, kind, False, detail, family="distribution")
    n_decisions = int(np.count_nonzero(decide(a_arr, SEQUENCE_STRATEGY)[0] != decide(b_arr, SEQUENCE_STRATEGY)[0]))
    largest = float(np.abs(a_arr - b_arr).max()) if a_arr.size else 0.0
    detail = f"{n_decisions} decisions differ; max |diff| {largest:.2e}"
    passed = n_decisions == 0 and largest <= WPROB_ROUNDING
    return Comparison(
        check, a_name, b_name, kind, passed, detail, n_decisions, max_abs_difference=largest, family="distribution"
    )


def compare_runs(prefix: str, a_name: str, a: SpikeRun, b_name: str, b: SpikeRun) -> list[Comparison]:
    """Exact comparisons of every SpikeRun field both runs report; the W+Prob distributions within rounding."""
    checks = [
        exact_comparison(
            f"{prefix}: {name.removesuffix('_per_step')}", a_name, getattr(a, name), b_name, getattr(b, name)
        )
        for name in RUN_FIELDS
        if getattr(a, name) is not None and getattr(b, name) is not None
    ]
    if a.wprob is not None and b.wprob is not None:
        checks.append(distribution_comparison(f"{prefix}: W+Prob head", "readout", a.wprob, b_name, b.wprob))
    return checks


def compare_models(prefix: str, a: FixedPointModel, b: FixedPointModel) -> list[Comparison]:
    """A fixed-point model read back from a file (``b``) against the one written: every integer and the config."""
    arrays = ("weight_mantissa", "threshold", "scale_multiplier", "calibration", "reference_place_ids")
    scalars = [[m.bits, m.scale_exponent, m.decay_dv, m.voltage_shift, m.voltage_bits] for m in (a, b)]
    same = a.config.to_dict() == b.config.to_dict()
    detail = "identical" if same else "configs differ"
    a_name, b_name = "written model", "read back"
    return [
        *(exact_comparison(f"{prefix}: {name}", a_name, getattr(a, name), b_name, getattr(b, name)) for name in arrays),
        exact_comparison(f"{prefix}: bits, exponent, decay, shift, width", a_name, scalars[0], b_name, scalars[1]),
        Comparison(f"{prefix}: config", a_name, b_name, "exact", same, detail, int(not same), family="config"),
    ]


def wprob_readout(source: Network) -> Callable[[np.ndarray], np.ndarray]:
    """counts (N, neurons) -> the W+Prob distribution (N, places) with the source's own calibration
    (an ensemble's with its region regularisation, as every evaluation reads it out)."""
    readout = Readout.of(source.calibration, source.config)
    return lambda counts: readout.scores(counts)[SEQUENCE_STRATEGY]


@dataclass(frozen=True)
class Contender:
    """A backend checked against the baseline, under the label its checks carry: on the first ``n_queries``
    presentations only (the slow reference stepper); ``written``/``read_back``, the model written to a file and
    the one read back, are compared integer by integer first; ``runs_on`` names the backend in its checks (None:
    the backend's own name; a read-back model runs on the project's simulators)."""

    target: str  # "reference" or a registered target's name
    label: str
    backend: Backend
    n_queries: int | None = None
    written: FixedPointModel | None = None
    read_back: FixedPointModel | None = None
    runs_on: str | None = None


def read_back(target: str, path: Path, written: Network | None, device: torch.device | None = None) -> Contender:
    """The contender of one exported file: read it back and run it (onnxruntime runs the graph itself).

    InvalidValueError for a target that is not registered."""
    entry = TARGETS.get(target)
    rebuilt = entry.read(Path(path))
    if not isinstance(rebuilt, (Checkpoint, FixedPointModel)):
        return Contender(target, entry.label, rebuilt)
    runs_on = f"{entry.title} model on the {'simulator' if isinstance(rebuilt, FixedPointModel) else 'float network'}"
    contender = Contender(target, entry.label, open_backend(rebuilt, device=device)[1], runs_on=runs_on)
    if isinstance(written, FixedPointModel) and isinstance(rebuilt, FixedPointModel):
        return replace(contender, written=written, read_back=rebuilt)
    return contender


def compare_backends(
    baseline: Backend,
    contenders: Sequence[Contender],
    spikes: torch.Tensor,
    *,
    baseline_run: SpikeRun | None = None,
    wprob: Callable[[np.ndarray], np.ndarray] | None = None,
) -> list[Comparison]:
    """Run every contender on ``spikes`` (or its first n) and compare it with the baseline's run of the same.

    ``baseline_run`` is the baseline's recorded run of all of ``spikes`` when already made;
    ``wprob`` maps counts to the W+Prob distribution a contender's head must reproduce.
    """
    full = baseline.run(spikes, record=True) if baseline_run is None else baseline_run
    checks: list[Comparison] = []
    for contender in contenders:
        if contender.written is not None and contender.read_back is not None:
            checks += compare_models(contender.label, contender.written, contender.read_back)
        n = spikes.shape[0] if contender.n_queries is None else min(contender.n_queries, spikes.shape[0])
        if n == 0:
            continue
        # fewer: the first n rows of the baseline's run; saturations are a total: a run of its own
        base = full if n == spikes.shape[0] else replace(full.head(n), saturations=baseline.run(spikes[:n]).saturations)
        run = contender.backend.run(spikes[:n], record=True)
        if run.wprob is not None and base.wprob is None and wprob is not None:
            base = replace(base, wprob=wprob(as_array(base.counts)))
        checks += compare_runs(contender.label, baseline.name, base, contender.runs_on or contender.backend.name, run)
    return checks


def write_targets(
    model: FixedPointModel, folder: Path, targets: Sequence[str]
) -> tuple[dict[str, list[Path]], dict[str, str]]:
    """Write each target of ``model`` into ``folder``, in the registry's order (ONNX with its W+Prob head and raster):
    (files per target, the targets a writer refused with its InvalidValueError, e.g. ONNX without state isolation).
    InvalidValueError for a target that is not registered."""
    wanted = {TARGETS.get(name).name for name in targets}
    options = WriteOptions(source_sha256=model.source_sha256, conformance=True)
    files: dict[str, list[Path]] = {}
    skipped: dict[str, str] = {}
    for entry in (entry for entry in TARGETS.values() if entry.name in wanted):
        try:
            files[entry.name] = entry.write(model, folder / entry.filename, options)
        except InvalidValueError as exc:
            skipped[entry.name] = str(exc)
    return files, skipped


def exact_contenders(model: FixedPointModel, slow_queries: int, device: torch.device | None) -> list[Contender]:
    """Every registered exact-integer backend that runs the model alone (no exported file) and is not the
    baseline; a slow one on the first ``slow_queries`` presentations only (none when 0)."""
    kinds = [
        k for k in tagged(EXACT) if BASELINE not in k.tags and k.needs is None and (slow_queries or SLOW not in k.tags)
    ]
    opened = [(kind, open_backend(model, kind.name, device=device)[1]) for kind in kinds]
    return [Contender(k.name, b.name, b, n_queries=slow_queries if SLOW in k.tags else None) for k, b in opened]


def cross_implementation(
    model: FixedPointModel,
    spikes: torch.Tensor,
    int_run: SpikeRun | None = None,
    *,
    folder: Path,
    targets: Sequence[str] | None = None,
    reference_queries: int = 3,
    device: torch.device | None = None,
    extra: Sequence[Contender] = (),
) -> ConformanceResult:
    """Write every requested target into ``folder``, read it back and run it; compare everything exactly.

    The baseline is the integer simulator (``int_run``: its recorded run of ``spikes``, when already made); every
    other exact backend runs beside it, a slow one on the first ``reference_queries`` presentations, and the
    ``extra`` contenders too (a tampered backend in the tests). ``targets``: registered names (None: all).
    """
    files, skipped = write_targets(model, Path(folder), TARGETS.names() if targets is None else targets)
    n_ref = int(min(max(reference_queries, 0), spikes.shape[0]))
    read = [read_back(t, TARGETS.get(t).reader_path(paths), model, device) for t, paths in files.items()]
    contenders = [*exact_contenders(model, n_ref, device), *read, *extra]
    baseline = open_backend(model, tagged(EXACT, BASELINE)[0].name, device=device)[1]
    checks = compare_backends(baseline, contenders, spikes, baseline_run=int_run, wprob=wprob_readout(model))
    return ConformanceResult(
        comparisons=tuple(checks),
        reference_queries=n_ref,
        skipped=skipped,
        files={t: tuple(str(p) for p in paths) for t, paths in files.items()},
    )
