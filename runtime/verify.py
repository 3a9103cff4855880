"""Does the deployed network still recognise places like the float one? The checks of `vprsnn-export verify`.

For one float checkpoint and each weight bit width, the network is quantised, every
integer implementation runs on the very spike tensor the float network sees
(:func:`runtime.inference.query_spikes`), and four families of checks compare them:

* **cross-implementation** (exact): the integer simulator, the ONNX graph on
  onnxruntime, the NIR and Loihi-style files read back, and the slow reference
  stepper (first few queries) must produce identical rasters, counts, candidate
  counts, final voltages and saturation counts. Integer outputs are compared bit for
  bit; the ONNX W+Prob head (float64 arithmetic in another summation order) must give
  identical decisions and differ by at most ``WPROB_ROUNDING`` (reported).
* **spike level**: per-step agreement of the float and integer rasters (the WTA winner),
  the per-query Pearson correlation of the two spike-count vectors, total spikes,
  saturation events.
* **decision level**: top-1 agreement with the float decisions for every strategy, the
  total-variation distance between the two W+Prob distributions, and the agreement of
  the k-frame aggregated decisions.
* **metric level**: accuracy, P@100R, R@100P and AUC-PR of Standard, Weighted and W+Prob
  at k=1 and W+Prob aggregated at each k, and their differences from float.

Tolerances (docs/verify.md) turn the metric, spike and decision differences into
pass/fail per bit width. Every function below is pure apart from :func:`verify_checkpoint`
(which writes the exported files) and returns plain JSON values.
"""

from __future__ import annotations

import dataclasses
import datetime
import importlib.metadata as md
import platform
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from vprsnn_export.dynamics import FloatNetwork
from vprsnn_export.encoding import query_spikes
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import check_bits, save_fixed_point
from vprsnn_export.readout.assignment import STRATEGIES, decide, strategy_scores
from vprsnn_export.readout.metrics import is_correct, pr_curve, predicted_place_ids
from vprsnn_export.stats import mean_std
from vprsnn_export.targets.intsim import IntegerNetwork, step_agreement
from vprsnn_export.version import __version__

from .conformance import check_conformance
from .deployment import deploy
from .evaluation import ReadoutOptions, aggregated, readout_rows
from .exporting import TARGETS, write_targets

SCHEMA = "vprsnn-verify-report/1"
METRICS = ("accuracy", "p_at_100r", "r_at_100p", "auc_pr")

#: Default tolerances: a *drop* of at most this much from float (fractions, 0.01 = 1 point).
DEFAULT_TOLERANCES: dict[str, float | None] = {
    "accuracy": 0.02,  # accuracy of Standard, Weighted and W+Prob at k=1
    "r_at_100p": 0.01,  # R@100P of W+Prob aggregated at the largest k
    "auc_pr": None,  # AUC-PR of W+Prob at the largest k (off by default)
    "p_at_100r": None,  # P@100R of every strategy at k=1 (equals accuracy; off by default)
    "winner_agreement": None,  # minimum fraction of steps with the float winner (off by default)
    "top1_agreement": None,  # minimum W+Prob k=1 top-1 agreement with float (off by default)
    "saturations": None,  # maximum saturation events on the queries (off by default)
    "query_slack": 1,  # a metric drop worth at most this many queries (n / Q) always passes
}
TOLERANCE_MEANING = {
    "accuracy": "accuracy drop of every strategy at k=1",
    "r_at_100p": "R@100P drop of W+Prob at the largest k",
    "auc_pr": "AUC-PR drop of W+Prob at the largest k",
    "p_at_100r": "P@100R drop of every strategy at k=1",
    "winner_agreement": "fraction of time steps with the float winner, at least",
    "top1_agreement": "W+Prob k=1 top-1 agreement with float, at least",
    "saturations": "voltage saturation events on the queries, at most",
    "query_slack": "metric drops of at most this many queries' worth (n / Q) pass whatever the limit",
}
MINIMUM_KEYS = ("winner_agreement", "top1_agreement")
OFF = ("off", "none", "")


# ---------------------------------------------------------------------------- options


def parse_tolerances(text: str | None, base: Mapping[str, float | None] | None = None) -> dict[str, float | None]:
    """``"r_at_100p=0.01,accuracy=0.02,auc_pr=off"`` over the defaults; InvalidValueError on anything else."""
    tolerances = dict(DEFAULT_TOLERANCES if base is None else base)
    for item in (text or "").split(","):
        if not item.strip():
            continue
        key, sep, raw = item.partition("=")
        key, raw = key.strip(), raw.strip().lower()
        if not sep or key not in DEFAULT_TOLERANCES:
            raise InvalidValueError(
                f"--tolerance expects KEY=VALUE with KEY one of {', '.join(DEFAULT_TOLERANCES)} (VALUE a number or off), got {item!r}"
            )
        if raw in OFF:
            tolerances[key] = None
            continue
        try:
            value = float(raw)
        except ValueError:
            raise InvalidValueError(f"--tolerance {key}: expected a number or off, got {raw!r}") from None
        if not np.isfinite(value) or value < 0:
            raise InvalidValueError(f"--tolerance {key}: expected a finite number >= 0, got {raw!r}")
        tolerances[key] = value
    return tolerances


@dataclass(frozen=True)
class VerifyOptions:
    """What `verify` quantises and how it reads out and judges."""

    readout: ReadoutOptions
    bits: tuple[int, ...] = (8, 6, 4, 3, 2)
    per_neuron: bool = True
    scale_method: str = "max"
    calibration: str = "deployed"  # "deployed": S^R re-measured on the integer simulator; "float": reused
    reference_queries: int = 3  # presentations run on the slow reference stepper
    targets: tuple[str, ...] = TARGETS
    tolerances: dict = field(default_factory=lambda: dict(DEFAULT_TOLERANCES))

    def to_dict(self) -> dict[str, Any]:
        data = dataclasses.asdict(self)
        data["readout"] = dataclasses.asdict(self.readout)
        return data


# ---------------------------------------------------------------------------- spike level


def count_correlations(float_counts: np.ndarray, int_counts: np.ndarray) -> np.ndarray:
    """Pearson correlation of the float and integer spike-count vectors (over neurons), one per query.

    Where a vector is constant the correlation is undefined: two identical vectors (e.g. both
    silent) count as 1, otherwise 0.
    """
    a = np.asarray(float_counts, dtype=np.float64)
    b = np.asarray(int_counts, dtype=np.float64)
    da, db = a - a.mean(axis=1, keepdims=True), b - b.mean(axis=1, keepdims=True)
    na, nb = np.sqrt((da * da).sum(axis=1)), np.sqrt((db * db).sum(axis=1))
    defined = (na > 0) & (nb > 0)
    corr = np.where(defined, (da * db).sum(axis=1) / np.where(defined, na * nb, 1.0), 0.0)
    identical = np.all(a == b, axis=1)
    return np.where(~defined & identical, 1.0, corr)


def spike_level(
    float_raster: torch.Tensor,
    int_raster: torch.Tensor,
    float_counts: np.ndarray,
    int_counts: np.ndarray,
    saturations: int,
) -> dict[str, Any]:
    """Winner agreement per step, spike-count correlation per query, total spikes, saturations."""
    agreement = step_agreement(torch.as_tensor(float_raster), torch.as_tensor(int_raster))
    corr = count_correlations(float_counts, int_counts)
    float_total = np.asarray(float_counts).sum(axis=1)
    int_total = np.asarray(int_counts).sum(axis=1)
    return {
        "winner_agreement": agreement["all_steps"],
        "winner_agreement_active": agreement["active_steps"],
        "n_steps": agreement["n_steps"],
        "n_active_steps": agreement["n_active_steps"],
        "count_correlation_mean": float(corr.mean()),
        "count_correlation_min": float(corr.min()),
        "count_correlation": [round(float(c), 6) for c in corr],
        "total_spikes_float": int(float_total.sum()),
        "total_spikes": int(int_total.sum()),
        "spike_ratio": float(int_total.sum() / float_total.sum()) if float_total.sum() else None,
        "spikes_per_query_float": [int(v) for v in float_total],
        "spikes_per_query": [int(v) for v in int_total],
        "saturations": int(saturations),
    }


# ---------------------------------------------------------------------------- decision level


def tv_distance(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Total variation distance 1/2 sum_l |p(l) - q(l)| per row, in [0, 1]."""
    return 0.5 * np.abs(np.asarray(p, dtype=np.float64) - np.asarray(q, dtype=np.float64)).sum(axis=1)


def top1_agreement(scores_a: np.ndarray, scores_b: np.ndarray, strategy: str) -> float:
    """Fraction of queries with the same decision (the same place, or both no-match)."""
    return float(np.mean(decide(scores_a, strategy)[0] == decide(scores_b, strategy)[0]))


def decision_level(
    float_scores: Mapping[str, np.ndarray],
    int_scores: Mapping[str, np.ndarray],
    float_aggregated: Mapping[int, np.ndarray],
    int_aggregated: Mapping[int, np.ndarray],
) -> dict[str, Any]:
    """Top-1 agreement per strategy at k=1, W+Prob total variation, aggregated agreement per k."""
    tv = tv_distance(float_scores["wprob"], int_scores["wprob"])
    return {
        "top1_agreement": {s: top1_agreement(float_scores[s], int_scores[s], s) for s in STRATEGIES},
        "wprob_tv_mean": float(tv.mean()),
        "wprob_tv_max": float(tv.max()),
        "wprob_tv": [round(float(v), 6) for v in tv],
        "aggregated_agreement": {
            str(k): top1_agreement(float_aggregated[k], int_aggregated[k], "wprob") for k in sorted(float_aggregated)
        },
    }


# ---------------------------------------------------------------------------- metric level


def readout_scores(calibration: np.ndarray, counts: np.ndarray, options: ReadoutOptions) -> tuple[dict, dict]:
    """Scores of every strategy at k=1 and the W+Prob aggregate at every k (k=1 included)."""
    scores = {s: strategy_scores(calibration, counts, s, options.gamma) for s in STRATEGIES}
    agg = {k: aggregated(scores["wprob"], k, options, None) for k in sorted(set(options.ks) | {1})}
    return scores, agg


def metric_deltas(float_rows: Sequence[dict], rows: Sequence[dict]) -> list[dict]:
    """Each quantised row with its float value and the difference (quantised - float) of every metric."""
    reference = {(r["strategy"], r["k"]): r for r in float_rows}
    out = []
    for row in rows:
        base = reference[(row["strategy"], row["k"])]
        out.append(
            {
                **row,
                "float": {m: base[m] for m in METRICS},
                "delta": {m: row[m] - base[m] for m in METRICS},
            }
        )
    return out


def pr_points(
    distribution: np.ndarray,
    strategy: str,
    reference_place_ids: np.ndarray,
    query_place_ids: np.ndarray,
    tolerance: int,
) -> dict[str, list[float]]:
    """The exact PR operating points of one score matrix, for the report's plots."""
    predicted, confidence = decide(distribution, strategy)
    correct = is_correct(predicted_place_ids(predicted, np.asarray(reference_place_ids)), query_place_ids, tolerance)
    precision, recall, _ = pr_curve(correct, confidence)
    return {"precision": [round(float(p), 6) for p in precision], "recall": [round(float(r), 6) for r in recall]}


def curves(
    scores: Mapping[str, np.ndarray], agg: Mapping[int, np.ndarray], reference_ids, query_ids, options: ReadoutOptions
) -> dict[str, dict]:
    """PR curves of W+Prob at k=1 and at the largest k."""
    out = {"wprob k=1": pr_points(scores["wprob"], "wprob", reference_ids, query_ids, options.tolerance)}
    top = max(options.ks)
    if top > 1:
        out[f"wprob k={top}"] = pr_points(agg[top], "wprob", reference_ids, query_ids, options.tolerance)
    return out


# ---------------------------------------------------------------------------- tolerances


def _row(rows: Sequence[dict], strategy: str, k: int) -> dict:
    return next(r for r in rows if r["strategy"] == strategy and r["k"] == k)


def tolerance_checks(
    rows: Sequence[dict],
    spike: Mapping[str, Any],
    decision: Mapping[str, Any],
    tolerances: Mapping[str, float | None],
    ks: Sequence[int],
) -> list[dict]:
    """Each enabled tolerance as {check, what, value, limit, passed}; ``rows`` come from :func:`metric_deltas`.

    Metric tolerances bound the drop from float (float - quantised <= limit): a quantised
    network that does better than float never fails. A metric moves in steps of 1/Q (one
    query of Q), so the limit applied is max(limit, query_slack / Q): with 30 queries a
    "1 point" limit would otherwise mean "no query may change". 1e-12 absorbs float rounding.
    """
    top = max(ks)
    checks = []
    n_queries = int(rows[0]["n_queries"]) if rows else 1
    slack = float(tolerances.get("query_slack") or 0) / max(n_queries, 1)

    def drop(name: str, strategy: str, k: int, metric: str) -> None:
        row = _row(rows, strategy, k)
        value = 0.0 - row["delta"][metric]
        limit = tolerances[name]
        applied = max(limit, slack)
        checks.append(
            {
                "check": name,
                "what": f"{metric} drop, {strategy} k={k}",
                "value": value,
                "limit": limit,
                "applied_limit": applied,
                "passed": bool(value <= applied + 1e-12),
            }
        )

    if tolerances.get("accuracy") is not None:
        for strategy in STRATEGIES:
            drop("accuracy", strategy, 1, "accuracy")
    if tolerances.get("p_at_100r") is not None:
        for strategy in STRATEGIES:
            drop("p_at_100r", strategy, 1, "p_at_100r")
    if tolerances.get("r_at_100p") is not None:
        drop("r_at_100p", "wprob", top, "r_at_100p")
    if tolerances.get("auc_pr") is not None:
        drop("auc_pr", "wprob", top, "auc_pr")
    if tolerances.get("winner_agreement") is not None:
        value, limit = spike["winner_agreement"], tolerances["winner_agreement"]
        checks.append(
            {
                "check": "winner_agreement",
                "what": "steps with the float winner",
                "value": value,
                "limit": limit,
                "applied_limit": limit,
                "passed": bool(value >= limit),
            }
        )
    if tolerances.get("top1_agreement") is not None:
        value, limit = decision["top1_agreement"]["wprob"], tolerances["top1_agreement"]
        checks.append(
            {
                "check": "top1_agreement",
                "what": "W+Prob k=1 top-1 agreement",
                "value": value,
                "limit": limit,
                "applied_limit": limit,
                "passed": bool(value >= limit),
            }
        )
    if tolerances.get("saturations") is not None:
        value, limit = spike["saturations"], tolerances["saturations"]
        checks.append(
            {
                "check": "saturations",
                "what": "saturation events on the queries",
                "value": value,
                "limit": limit,
                "applied_limit": limit,
                "passed": bool(value <= limit),
            }
        )
    return checks


# ---------------------------------------------------------------------------- weights


def weight_histograms(float_weights: np.ndarray, per_neuron: bool, bins: int = 64) -> dict[str, Any]:
    """Histogram of the float weights divided by their scale range (per-neuron or global maximum)."""
    w = np.asarray(float_weights, dtype=np.float64)
    top = w.max(axis=0, keepdims=True) if per_neuron else np.array([[w.max()]])
    ratio = w / np.where(top > 0, top, 1.0)
    counts, edges = np.histogram(ratio, bins=bins, range=(0.0, 1.0))
    return {
        "normalised_by": "per-neuron maximum" if per_neuron else "global maximum",
        "counts": [int(c) for c in counts],
        "edges": [round(float(e), 6) for e in edges],
    }


def level_histogram(model) -> dict[str, Any]:
    """How many weights sit on each mantissa level 0 .. 2**bits - 1."""
    levels = (1 << model.bits) - 1
    counts = np.bincount(np.asarray(model.weight_mantissa).ravel().astype(np.int64), minlength=levels + 1)
    return {
        "levels": levels,
        "counts": [int(c) for c in counts[: levels + 1]],
        "zero_fraction": float(counts[0] / max(counts.sum(), 1)),
    }


# ---------------------------------------------------------------------------- orchestration


def verify_checkpoint(
    ckpt,
    ckpt_sha256: str,
    query_images: np.ndarray,
    query_place_ids: np.ndarray,
    query_traversal: str,
    options: VerifyOptions,
    *,
    reference_images: Mapping[str, np.ndarray] | None = None,
    export_dir: str | Path | None = None,
    device: torch.device | None = None,
    progress: bool = False,
    label: str | None = None,
) -> dict[str, Any]:
    """Quantise ``ckpt`` at every bit width and run every check; a JSON-ready dict (one report run).

    ``reference_images`` (the checkpoint's reference traversals, in its reference place
    order) are needed for the deployed calibration; ``export_dir`` receives each bit
    width's fixed-point model and exported files (a temporary folder when None).
    """
    device = torch.device("cpu") if device is None else device
    bits_list = [check_bits(b) for b in options.bits]
    if options.calibration not in ("deployed", "float"):
        raise InvalidValueError(f"calibration must be deployed or float, got {options.calibration!r}")
    if options.calibration == "deployed" and reference_images is None:
        raise InvalidValueError("the deployed calibration needs the reference images")
    readout = options.readout
    query_place_ids = np.asarray(query_place_ids, dtype=np.int64)
    spikes = query_spikes(query_images, query_place_ids, query_traversal, ckpt.config)
    float_run = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, ckpt.config, device).run(spikes, record=True)
    float_counts = float_run.counts.numpy()
    ref_ids = ckpt.reference_place_ids
    float_rows = readout_rows(ckpt.calibration, float_counts, ref_ids, query_place_ids, readout)
    float_scores, float_agg = readout_scores(ckpt.calibration, float_counts, readout)
    temporary = tempfile.TemporaryDirectory(prefix="vprsnn-verify-") if export_dir is None else None
    root = Path(temporary.name if temporary else export_dir)
    results = []
    stages = tqdm(
        total=len(bits_list) * 4,
        desc=f"verify {label or ''}".strip(),
        unit="stage",
        file=sys.stderr,
        disable=not progress,
        leave=False,
    )
    try:
        for bits in bits_list:
            clock = time.perf_counter()
            seconds: dict[str, float] = {}
            stages.set_postfix(bits=bits, stage="quantise")
            model = deploy(
                ckpt,
                ckpt_sha256,
                bits,
                per_neuron=options.per_neuron,
                scale_method=options.scale_method,
                calibration=options.calibration,
                reference_images=reference_images,
                device=device,
            )
            folder = root / f"{bits}bit"
            model_path = save_fixed_point(folder / "model.npz", model)
            seconds["quantise_and_calibrate"], clock = time.perf_counter() - clock, time.perf_counter()
            stages.update(1)
            stages.set_postfix(bits=bits, stage="simulate")
            int_run = IntegerNetwork(model, device).run(spikes, record=True)
            int_counts = int_run.counts.numpy()
            seconds["integer_simulator"], clock = time.perf_counter() - clock, time.perf_counter()
            stages.update(1)
            stages.set_postfix(bits=bits, stage="targets")
            written, skipped = write_targets(
                model, model, options.targets, folder, digest=model.source_sha256, onnx_raster=True
            )
            cross = check_conformance(
                model,
                spikes,
                int_run,
                written,
                reference_queries=options.reference_queries,
                skipped=skipped,
                device=device,
            ).to_dict()
            cross["files"]["model"] = [str(model_path)]
            seconds["targets_and_reference"], clock = time.perf_counter() - clock, time.perf_counter()
            stages.update(1)
            stages.set_postfix(bits=bits, stage="readout")
            rows = metric_deltas(
                float_rows, readout_rows(model.calibration, int_counts, ref_ids, query_place_ids, readout)
            )
            scores, agg = readout_scores(model.calibration, int_counts, readout)
            spike = spike_level(float_run.raster, int_run.raster, float_counts, int_counts, int_run.saturations)
            spike["calibration_saturations"] = model.quantisation.get("calibration_saturations")
            decision = decision_level(
                float_scores, scores, {k: float_agg[k] for k in readout.ks}, {k: agg[k] for k in readout.ks}
            )
            checks = tolerance_checks(rows, spike, decision, options.tolerances, readout.ks)
            seconds["readout"] = time.perf_counter() - clock
            results.append(
                {
                    "bits": bits,
                    "quantisation": model.quantisation,
                    "cross_implementation": cross,
                    "spike_level": spike,
                    "decision_level": decision,
                    "metrics": rows,
                    "tolerance_checks": checks,
                    "pr_curves": curves(scores, agg, ref_ids, query_place_ids, readout),
                    "weight_levels": level_histogram(model),
                    "passed": bool(cross["passed"] and all(c["passed"] for c in checks)),
                    "seconds": {k: round(v, 3) for k, v in seconds.items()},
                }
            )
            stages.update(1)
    finally:
        stages.close()
        if temporary is not None:
            temporary.cleanup()
    return {
        "label": label,
        "seed": ckpt.config.seed,
        "config": ckpt.config.to_dict(),
        "checkpoint_sha256": ckpt_sha256,
        "checkpoint_data": ckpt.data,
        "query": query_traversal,
        "n_queries": int(len(query_place_ids)),
        "query_place_ids": [int(p) for p in query_place_ids],
        "reference_place_ids": [int(p) for p in ref_ids],
        "export_dir": None if temporary else str(root),
        "float": {
            "metrics": float_rows,
            "total_spikes": int(float_counts.sum()),
            "pr_curves": curves(float_scores, float_agg, ref_ids, query_place_ids, readout),
            "weights": weight_histograms(ckpt.weights, options.per_neuron),
        },
        "bits": results,
        "passed": all(r["passed"] for r in results),
    }


# ---------------------------------------------------------------------------- the report


def summarise_runs(runs: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Mean ± std over runs (independently trained networks) of every metric and check, per bit width."""
    float_groups: dict[tuple, list[dict]] = {}
    for run in runs:
        for row in run["float"]["metrics"]:
            float_groups.setdefault((row["strategy"], row["k"]), []).append(row)
    float_rows = [
        {"strategy": s, "k": k, **{m: mean_std([r[m] for r in rows]).to_dict() for m in METRICS}}
        for (s, k), rows in float_groups.items()
    ]
    per_bits: dict[int, list[dict]] = {}
    for run in runs:
        for result in run["bits"]:
            per_bits.setdefault(int(result["bits"]), []).append(result)
    bits_summary = []
    for bits in sorted(per_bits, reverse=True):
        results = per_bits[bits]
        groups: dict[tuple, list[dict]] = {}
        for result in results:
            for row in result["metrics"]:
                groups.setdefault((row["strategy"], row["k"]), []).append(row)
        rows = [
            {
                "strategy": s,
                "k": k,
                **{m: mean_std([r[m] for r in rs]).to_dict() for m in METRICS},
                "delta": {m: mean_std([r["delta"][m] for r in rs]).to_dict() for m in METRICS},
            }
            for (s, k), rs in groups.items()
        ]
        ks = sorted({int(k) for r in results for k in r["decision_level"]["aggregated_agreement"]})
        bits_summary.append(
            {
                "bits": bits,
                "n_runs": len(results),
                "n_passed": sum(bool(r["passed"]) for r in results),
                "cross_implementation_passed": sum(bool(r["cross_implementation"]["passed"]) for r in results),
                "metrics": rows,
                "winner_agreement": mean_std([r["spike_level"]["winner_agreement"] for r in results]).to_dict(),
                "count_correlation": mean_std([r["spike_level"]["count_correlation_mean"] for r in results]).to_dict(),
                "spike_ratio": mean_std([r["spike_level"]["spike_ratio"] for r in results]).to_dict(),
                "saturations": mean_std([r["spike_level"]["saturations"] for r in results]).to_dict(),
                "top1_agreement": {
                    s: mean_std([r["decision_level"]["top1_agreement"][s] for r in results]).to_dict()
                    for s in STRATEGIES
                },
                "wprob_tv_mean": mean_std([r["decision_level"]["wprob_tv_mean"] for r in results]).to_dict(),
                "aggregated_agreement": {
                    str(k): mean_std(
                        [r["decision_level"]["aggregated_agreement"].get(str(k)) for r in results]
                    ).to_dict()
                    for k in ks
                },
            }
        )
    return {
        "n_runs": len(runs),
        "float": float_rows,
        "bits": bits_summary,
        "passed": all(bool(r["passed"]) for r in runs),
    }


def versions() -> dict[str, str]:
    """Package and library versions recorded in every report."""
    out = {
        "vprsnn-export": __version__,
        "python": platform.python_version(),
        "platform": platform.platform(),
        "machine": f"{platform.machine()}, {torch.get_num_threads()} torch threads",
    }
    for name in ("torch", "numpy", "onnx", "onnxruntime", "nir", "h5py", "matplotlib"):
        try:
            out[name] = md.version(name)
        except md.PackageNotFoundError:
            out[name] = "absent"
    return out


def build_report(
    runs: Sequence[Mapping[str, Any]],
    settings: Mapping[str, Any],
    *,
    command: Sequence[str] | None = None,
    seconds: float | None = None,
) -> dict[str, Any]:
    """The whole report.json: settings, versions, every run, the summary and the verdict."""
    return {
        "schema": SCHEMA,
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "command": list(command) if command is not None else None,
        "seconds": None if seconds is None else round(float(seconds), 1),
        "versions": versions(),
        "settings": dict(settings),
        "runs": list(runs),
        "summary": summarise_runs(runs),
        "passed": all(bool(r["passed"]) for r in runs),
    }


__all__ = [
    "DEFAULT_TOLERANCES",
    "SCHEMA",
    "VerifyOptions",
    "build_report",
    "count_correlations",
    "decision_level",
    "metric_deltas",
    "parse_tolerances",
    "spike_level",
    "summarise_runs",
    "tolerance_checks",
    "top1_agreement",
    "tv_distance",
    "verify_checkpoint",
]
