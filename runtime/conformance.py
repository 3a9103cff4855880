"""Do the deployment files compute the same network? Backends compared field by field on the same spikes.

Every implementation of a fixed-point model (the integer simulator, its slow reference
stepper, onnxruntime on the ONNX graph, the NIR and Loihi-style files read back and run
on the simulator) is a :class:`~vprsnn_export.runs.Backend` returning a
:class:`~vprsnn_export.runs.SpikeRun`. One baseline run is compared with every other
backend's run of the very same spike tensor, exactly: every field both runs report
(raster, counts, candidates per step, final voltages, saturations) must be identical,
and a W+Prob distribution computed by the backend itself (the ONNX head, float64 in
another summation order) must give identical decisions and differ by at most
``WPROB_ROUNDING``. `verify` and `export --check` both use this module.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.readout.assignment import decide, strategy_scores
from vprsnn_export.runs import Backend, SpikeRun
from vprsnn_export.targets.intsim import IntegerNetwork
from vprsnn_export.targets.loihi_target import read_loihi_model
from vprsnn_export.targets.nir_target import read_nir
from vprsnn_export.targets.onnx_target import OnnxBackend
from vprsnn_export.targets.reference_stepper import ReferenceStepper

WPROB_ROUNDING = 1e-12  # largest |P_backend - P_readout| allowed for a float64 W+Prob head

#: The SpikeRun fields compared exactly, with the names the reports use.
RUN_FIELDS = (
    ("raster", "raster"),
    ("counts", "counts"),
    ("candidates_per_step", "candidates"),
    ("final_voltage", "final_voltage"),
    ("saturations", "saturations"),
)


@dataclass(frozen=True)
class Comparison:
    """One check of one quantity between two implementations ``a`` and ``b``."""

    check: str
    a: str
    b: str
    kind: str
    equal: bool
    detail: str
    n_elements: int | None = None
    n_differences: int | None = None
    first_difference: list[int] | None = None
    max_abs_difference: float | None = None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"check": self.check, "a": self.a, "b": self.b, "kind": self.kind, "equal": self.equal}
        if self.max_abs_difference is not None or self.kind != "exact":
            out["max_abs_difference"] = self.max_abs_difference
        else:
            out["n_elements"] = self.n_elements
            out["first_difference"] = self.first_difference
        out["n_differences"] = self.n_differences
        out["detail"] = self.detail
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Comparison:
        return cls(
            check=str(data["check"]),
            a=str(data["a"]),
            b=str(data["b"]),
            kind=str(data["kind"]),
            equal=bool(data["equal"]),
            detail=str(data.get("detail", "")),
            n_elements=data.get("n_elements"),
            n_differences=data.get("n_differences"),
            first_difference=data.get("first_difference"),
            max_abs_difference=data.get("max_abs_difference"),
        )


@dataclass(frozen=True)
class Conformance:
    """Every comparison of one model's backends, the files they read and what could not run."""

    comparisons: tuple[Comparison, ...]
    reference_queries: int = 0
    skipped: dict[str, str] = field(default_factory=dict)
    files: dict[str, list[str]] = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return all(c.equal for c in self.comparisons)

    @property
    def n_failed(self) -> int:
        return sum(not c.equal for c in self.comparisons)

    def to_dict(self) -> dict[str, Any]:
        return {
            "checks": [c.to_dict() for c in self.comparisons],
            "passed": self.passed,
            "n_checks": len(self.comparisons),
            "n_failed": self.n_failed,
            "reference_queries": self.reference_queries,
            "skipped": dict(self.skipped),
            "files": {k: list(v) for k, v in self.files.items()},
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Conformance:
        return cls(
            comparisons=tuple(Comparison.from_dict(c) for c in data.get("checks", [])),
            reference_queries=int(data.get("reference_queries", 0)),
            skipped=dict(data.get("skipped", {})),
            files={k: list(v) for k, v in data.get("files", {}).items()},
        )


def as_numpy(value: Any) -> np.ndarray:
    """A tensor, array or scalar as a numpy array (on the CPU)."""
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().numpy()
    return np.asarray(value)


def exact_comparison(check: str, a_name: str, a: Any, b_name: str, b: Any) -> Comparison:
    """Bit-for-bit equality of two arrays (or integers): any difference fails."""
    a_arr, b_arr = as_numpy(a), as_numpy(b)
    if a_arr.shape != b_arr.shape:
        return Comparison(
            check, a_name, b_name, "exact", False, f"shapes differ: {a_arr.shape} vs {b_arr.shape}", int(a_arr.size)
        )
    differ = a_arr != b_arr
    n_diff = int(np.count_nonzero(differ))
    if n_diff == 0:
        return Comparison(check, a_name, b_name, "exact", True, f"identical ({a_arr.size} values)", int(a_arr.size), 0)
    first = [int(i) for i in np.unravel_index(int(np.flatnonzero(differ)[0]), differ.shape)]
    where = tuple(first)
    detail = f"{n_diff} of {a_arr.size} values differ; first at {first}: {a_arr[where]!r} vs {b_arr[where]!r}"
    return Comparison(check, a_name, b_name, "exact", False, detail, int(a_arr.size), n_diff, first)


def distribution_comparison(
    check: str, a_name: str, a: np.ndarray, b_name: str, b: np.ndarray, limit: float = WPROB_ROUNDING
) -> Comparison:
    """Two W+Prob distributions: identical decisions and max |a - b| <= limit (float64 rounding)."""
    a_arr, b_arr = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    kind = f"decisions exact, |diff| <= {limit:g}"
    if a_arr.shape != b_arr.shape:
        return Comparison(check, a_name, b_name, kind, False, f"shapes differ: {a_arr.shape} vs {b_arr.shape}")
    n_decisions = int(np.count_nonzero(decide(a_arr, "wprob")[0] != decide(b_arr, "wprob")[0]))
    largest = float(np.abs(a_arr - b_arr).max()) if a_arr.size else 0.0
    return Comparison(
        check,
        a_name,
        b_name,
        kind,
        bool(n_decisions == 0 and largest <= limit),
        f"{n_decisions} decisions differ; max |diff| {largest:.2e}",
        n_differences=n_decisions,
        max_abs_difference=largest,
    )


def compare_runs(prefix: str, a_name: str, a: SpikeRun, b_name: str, b: SpikeRun) -> list[Comparison]:
    """Exact comparisons of every SpikeRun field both runs report (rasters as booleans)."""
    checks = []
    for attribute, label in RUN_FIELDS:
        left, right = getattr(a, attribute), getattr(b, attribute)
        if left is None or right is None:
            continue
        if attribute == "raster":
            left, right = as_numpy(left).astype(bool), as_numpy(right).astype(bool)
        checks.append(exact_comparison(f"{prefix}: {label}", a_name, left, b_name, right))
    return checks


def compare_models(prefix: str, a_name: str, a: FixedPointModel, b_name: str, b: FixedPointModel) -> list[Comparison]:
    """A fixed-point model read back from a file against the one written: every integer and the config."""
    checks = [
        exact_comparison(f"{prefix}: {name}", a_name, getattr(a, name), b_name, getattr(b, name))
        for name in ("weight_mantissa", "threshold", "scale_multiplier", "calibration", "reference_place_ids")
    ]
    scalars_a = [a.bits, a.scale_exponent, a.decay_dv, a.voltage_shift, a.voltage_bits]
    scalars_b = [b.bits, b.scale_exponent, b.decay_dv, b.voltage_shift, b.voltage_bits]
    checks.append(
        exact_comparison(f"{prefix}: bits, exponent, decay, shift, width", a_name, scalars_a, b_name, scalars_b)
    )
    same = a.config.to_dict() == b.config.to_dict()
    checks.append(
        Comparison(
            f"{prefix}: config",
            a_name,
            b_name,
            "exact",
            same,
            "identical" if same else "configs differ",
            1,
            int(not same),
        )
    )
    return checks


@dataclass(frozen=True)
class ReadBack:
    """A deployment file read back: the model it describes, run on the integer simulator."""

    label: str  # "NIR", "Loihi"
    model: FixedPointModel
    backend: Backend


def read_back(files: Mapping[str, Sequence[Path]], device: torch.device | None = None) -> list[ReadBack]:
    """The NIR and Loihi-style files among ``files`` (target -> paths) rebuilt as fixed-point models."""
    out = []
    if "nir" in files:
        nir_model = read_nir(files["nir"][0])
        if isinstance(nir_model, FixedPointModel):
            out.append(ReadBack("NIR", nir_model, IntegerNetwork(nir_model, device, name="NIR model on the simulator")))
    if "loihi" in files:
        loihi_model = read_loihi_model(Path(files["loihi"][0]).parent)
        out.append(
            ReadBack("Loihi", loihi_model, IntegerNetwork(loihi_model, device, name="Loihi model on the simulator"))
        )
    return out


def check_conformance(
    model: FixedPointModel,
    spikes: torch.Tensor,
    baseline: SpikeRun,
    files: Mapping[str, Sequence[Path]],
    *,
    reference_queries: int = 0,
    skipped: Mapping[str, str] | None = None,
    device: torch.device | None = None,
) -> Conformance:
    """Compare the integer simulator's recorded ``baseline`` run with every other backend, exactly.

    The reference stepper runs the first ``reference_queries`` presentations; onnxruntime
    runs the ONNX file (counts, saturations, raster when the graph has it, and its W+Prob
    head against the readout of the baseline counts); NIR and Loihi-style files are read
    back, compared integer by integer with ``model`` and run on the simulator.
    """
    checks: list[Comparison] = []
    simulator = IntegerNetwork(model, device)
    n_ref = int(min(max(reference_queries, 0), spikes.shape[0]))
    if n_ref:
        # the baseline's own rows of these queries; saturations are totals, so they need a run of their own
        head = replace(baseline.head(n_ref), saturations=simulator.run(spikes[:n_ref]).saturations)
        oracle = ReferenceStepper(model).run(spikes[:n_ref], record=True)
        checks += compare_runs("reference stepper", simulator.name, head, "reference stepper", oracle)
    if "onnx" in files:
        onnx_backend = OnnxBackend(Path(files["onnx"][0]))
        onnx_run = onnx_backend.run(spikes, record=True)
        no_candidates = SpikeRun(counts=baseline.counts, raster=baseline.raster, saturations=baseline.saturations)
        checks += compare_runs("ONNX (onnxruntime)", simulator.name, no_candidates, onnx_backend.name, onnx_run)
        if onnx_run.wprob is not None:
            expected = strategy_scores(
                model.calibration, as_numpy(baseline.counts), "wprob", model.config.assignment.gamma
            )
            checks.append(
                distribution_comparison(
                    "ONNX (onnxruntime): W+Prob head", "readout", expected, onnx_backend.name, onnx_run.wprob
                )
            )
    for item in read_back(files, device):
        checks += compare_models(f"{item.label} read back", "written model", model, "read back", item.model)
        checks += compare_runs(
            f"{item.label} read back",
            simulator.name,
            baseline,
            item.backend.name,
            item.backend.run(spikes, record=True),
        )
    return Conformance(
        comparisons=tuple(checks),
        reference_queries=n_ref,
        skipped=dict(skipped or {}),
        files={target: [str(p) for p in paths] for target, paths in files.items()},
    )
