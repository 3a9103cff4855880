"""The verification checks: pure functions on small arrays, then the whole run on a tiny trained network."""

import dataclasses
import json

import numpy as np
import pytest
import torch

from vprsnn_export.cli import main
from vprsnn_export.config import Config
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.data.truth import EXACT, Query
from vprsnn_export.errors import EXIT_BAD_INPUT, InvalidValueError
from vprsnn_export.export.quantize import QuantiseOptions, quantize_checkpoint
from vprsnn_export.io.checkpoint import checkpoint_sha256, load_checkpoint, save_checkpoint
from vprsnn_export.network.runs import SpikeRun
from vprsnn_export.readout.compare import top1_agreement, tv_distance
from vprsnn_export.readout.scored import Scored
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.readout.strategies import STRATEGIES
from vprsnn_export.runtime.conformance import (
    Contender,
    cross_implementation,
    distribution_comparison,
    exact_comparison,
)
from vprsnn_export.runtime.report import write_report
from vprsnn_export.runtime.results import (
    SCHEMA,
    ConformanceResult,
    DecisionLevel,
    MetricRow,
    ModuleRow,
    SpikeLevel,
    VerifiedRun,
    VerifyReport,
)
from vprsnn_export.runtime.verify import (
    Runtime,
    VerifiedNetwork,
    VerifyOptions,
    build_report,
    summarise_runs,
    verify_checkpoint,
)
from vprsnn_export.runtime.verify import run as verify_module
from vprsnn_export.runtime.verify.checks import (
    DEFAULT_TOLERANCES,
    count_correlations,
    metric_deltas,
    module_rows,
    parse_tolerances,
    tolerance_checks,
)
from vprsnn_export.targets.intsim import IntegerNetwork
from vprsnn_export.targets.registry import TARGETS
from vprsnn_export.trainer.pipeline import train_and_calibrate

TINY = ["--timesteps", "40", "--epochs", "2", "--neurons", "48"]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    path = tmp_path_factory.mktemp("verify") / "net.npz"
    assert main(["train", "--data", "synthetic:20", "--reference", "summer", "--out", str(path), "--quiet", *TINY]) == 0
    ckpt = load_checkpoint(path)
    data = load_dataset("synthetic:20", ["summer", "winter"], ckpt.config.preprocess)
    return path, ckpt, data


@pytest.fixture(scope="module")
def verified(tiny, tmp_path_factory):
    path, ckpt, data = tiny
    options = VerifyOptions(readout=SequenceOptions(ks=(1, 3)), bits=(8, 2), reference_queries=2)
    run = verify_checkpoint(
        VerifiedNetwork(ckpt, checkpoint_sha256(path), {"summer": data.traversal("summer")}, "tiny"),
        Query("winter", data.traversal("winter"), data.place_ids),
        options,
        Runtime(export_dir=tmp_path_factory.mktemp("exports")),
    )
    return run


# ---------------------------------------------------------------- options


def test_tolerances_default_override_and_off():
    assert parse_tolerances(None) == DEFAULT_TOLERANCES
    tol = parse_tolerances("r_at_100p=0.05, accuracy=off,winner_agreement=0.9")
    assert tol["r_at_100p"] == 0.05 and tol["accuracy"] is None and tol["winner_agreement"] == 0.9
    assert tol["auc_pr"] is None and tol["query_slack"] == DEFAULT_TOLERANCES["query_slack"]


@pytest.mark.parametrize(
    "bad",
    [
        "nonsense=1",
        "accuracy",
        "accuracy=abc",
        "accuracy=-0.1",
        "r_at_100p=nan",
        "accuracy=5",  # a 500-point drop that can never fail
        "top1_agreement=1.5",  # a minimum share that can never hold
        "query_slack=0.5",  # half a query
        "saturations=inf",
        "accuracy=0.02,accuracy=0.03",  # given twice
    ],
)
def test_bad_tolerances_are_option_errors(bad):
    with pytest.raises(InvalidValueError) as info:
        parse_tolerances(bad)
    assert info.value.exit_code == EXIT_BAD_INPUT


# ---------------------------------------------------------------- exact comparisons


def test_exact_comparison_passes_identical_and_catches_one_flipped_bit():
    raster = np.random.default_rng(0).random((3, 10, 5)) > 0.7
    assert exact_comparison("raster", "a", raster, "b", raster.copy()).equal
    corrupt = raster.copy()
    corrupt[2, 7, 4] = ~corrupt[2, 7, 4]
    result = exact_comparison("raster", "a", raster, "b", torch.as_tensor(corrupt))
    assert not result.equal and result.n_differences == 1 and result.first_difference == (2, 7, 4)
    assert result.to_dict()["first_difference"] == [2, 7, 4]
    assert not exact_comparison("counts", "a", np.zeros((2, 3)), "b", np.zeros((3, 2))).equal
    assert not exact_comparison("saturations", "a", 0, "b", 1).equal


def test_distribution_comparison_allows_rounding_but_not_another_decision():
    p = np.array([[0.1, 0.6, 0.3], [0.5, 0.25, 0.25]])
    assert distribution_comparison("w", "a", p, "b", p + 1e-15).equal
    assert not distribution_comparison("w", "a", p, "b", p + 1e-9).equal  # beyond float64 rounding
    swapped = p.copy()
    swapped[0] = [0.1, 0.3, 0.6]
    result = distribution_comparison("w", "a", p, "b", swapped)
    assert not result.equal and result.n_differences == 1


# ---------------------------------------------------------------- spike and decision level


def test_count_correlations():
    a = np.array([[0, 1, 2, 3], [0, 0, 0, 0], [0, 0, 0, 0], [1, 2, 3, 4]])
    b = np.array([[0, 2, 4, 6], [0, 0, 0, 0], [0, 1, 0, 0], [4, 3, 2, 1]])
    np.testing.assert_allclose(count_correlations(a, b), [1.0, 1.0, 0.0, -1.0])


def scored(distribution: np.ndarray, ids: np.ndarray, aggregates: dict | None = None) -> Scored:
    """Every strategy of a readout given one distribution (Q, places), judged by exact place ids."""
    queries = ids[: len(distribution)]
    return Scored.of({s: distribution for s in STRATEGIES}, aggregates or {1: distribution}, ids, queries, EXACT)


def test_tv_distance_and_top1_agreement():
    p = np.array([[0.5, 0.5, 0.0], [1.0, 0.0, 0.0]])
    q = np.array([[0.5, 0.5, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(tv_distance(p, q), [0.0, 1.0])
    ids = np.arange(3)
    assert top1_agreement(scored(p, ids).column("wprob"), scored(q, ids).column("wprob")) == 0.5
    flat = scored(np.full((2, 3), 1 / 3), ids).column("wprob")
    assert top1_agreement(flat, flat) == 1.0  # both no-match: the same decision


def _rows(float_values, quant_values, n=50):
    def rows(values):
        return [
            {"strategy": s, "k": k, "accuracy": v, "p_at_100r": v, "r_at_100p": v, "auc_pr": v, "n_queries": n}
            for (s, k), v in zip([("standard", 1), ("weighted", 1), ("wprob", 1), ("wprob", 5)], values, strict=True)
        ]

    typed = [MetricRow.from_dict(r) for r in rows(float_values)], [MetricRow.from_dict(r) for r in rows(quant_values)]
    return metric_deltas(*typed)


def _levels(winner: float, saturations: int, top1: float) -> tuple[SpikeLevel, DecisionLevel]:
    spike = SpikeLevel(winner, winner, 10, 10, 1.0, 1.0, (1.0,), 10, 10, 1.0, (10,), (10,), saturations)
    decision = DecisionLevel({"standard": top1, "weighted": top1, "wprob": top1}, 0.0, 0.0, (0.0,), {1: top1})
    return spike, decision


def test_tolerance_checks_bound_drops_only():
    tol = parse_tolerances("query_slack=0")
    spike, decision = _levels(0.9, 0, 0.8)
    better = tolerance_checks(_rows([0.5] * 4, [0.9] * 4), spike, decision, tol, (1, 5))
    assert better and all(c.passed for c in better)
    worse = tolerance_checks(_rows([0.5, 0.5, 0.5, 0.8], [0.49, 0.5, 0.5, 0.78]), spike, decision, tol, (1, 5))
    verdicts = {c.what: c.passed for c in worse}
    assert verdicts["accuracy drop, standard k=1"] is True  # 1 point <= 2 points
    assert verdicts["r_at_100p drop, wprob k=5"] is False  # 2 points > 1 point
    strict = tolerance_checks(
        _rows([0.5] * 4, [0.5] * 4),
        spike,
        decision,
        parse_tolerances("winner_agreement=0.95,top1_agreement=0.8,saturations=0"),
        (1, 5),
    )
    assert {c.check: c.passed for c in strict if c.check in ("winner_agreement", "top1_agreement", "saturations")} == {
        "winner_agreement": False,
        "top1_agreement": True,
        "saturations": True,
    }


def test_r_at_100p_is_judged_at_every_k_and_sequences_only_on_consecutive_queries():
    tol = parse_tolerances("query_slack=0")
    spike, decision = _levels(1.0, 0, 1.0)
    rows = _rows([0.5, 0.5, 0.5, 0.8], [0.5, 0.5, 0.27, 0.8])  # W+Prob k=1 R@100P drops 23 points
    judged = {c.what: c.passed for c in tolerance_checks(rows, spike, decision, tol, (1, 5))}
    assert judged["r_at_100p drop, wprob k=1"] is False and judged["r_at_100p drop, wprob k=5"] is True
    scattered = tolerance_checks(rows, spike, decision, tol, (1, 5), sequences=False)
    assert not any("k=5" in c.what for c in scattered)
    assert "r_at_100p drop, wprob k=1" in {c.what for c in scattered}


def test_query_slack_allows_one_query_of_a_short_route():
    rows = _rows([0.5, 0.5, 0.5, 0.8], [0.5, 0.5, 0.5, 0.8 - 1 / 30], n=30)
    spike, decision = _levels(1.0, 0, 1.0)
    one = {c.what: c for c in tolerance_checks(rows, spike, decision, parse_tolerances(None), (1, 5))}
    assert one["r_at_100p drop, wprob k=5"].passed
    assert one["r_at_100p drop, wprob k=5"].applied_limit == pytest.approx(1 / 30)
    none = {c.what: c for c in tolerance_checks(rows, spike, decision, parse_tolerances("query_slack=0"), (1, 5))}
    assert not none["r_at_100p drop, wprob k=5"].passed


# ---------------------------------------------------------------- cross-implementation on a real model


@pytest.fixture(scope="module")
def model_and_spikes(tiny):
    path, ckpt, data = tiny
    model = quantize_checkpoint(ckpt, checkpoint_sha256(path), 4, QuantiseOptions())
    spikes = query_spikes(data.traversal("winter")[:6], data.place_ids[:6], "winter", ckpt.config)
    return model, spikes


def test_cross_implementation_is_exact(model_and_spikes, tmp_path):
    model, spikes = model_and_spikes
    run = IntegerNetwork(model).run(spikes, record=True)
    cross = cross_implementation(
        model, spikes, run, folder=tmp_path, targets=("onnx", "nir", "loihi"), reference_queries=2
    )
    assert cross.passed and cross.n_failed == 0 and cross.reference_queries == 2
    names = {c.check.split(":")[0] for c in cross.comparisons}
    assert names == {"reference stepper", "ONNX (onnxruntime)", "NIR read back", "Loihi read back"}
    assert (tmp_path / "model.onnx").is_file() and (tmp_path / "model.nir").is_file() and (tmp_path / "loihi").is_dir()


def test_cross_implementation_catches_one_corrupted_spike(model_and_spikes, tmp_path):
    model, spikes = model_and_spikes
    run = IntegerNetwork(model).run(spikes, record=True)
    raster = run.raster.clone()
    raster[1, 5, 0] = ~raster[1, 5, 0]
    corrupt = dataclasses.replace(run, raster=raster)
    cross = cross_implementation(model, spikes, corrupt, folder=tmp_path, targets=("onnx", "nir"), reference_queries=2)
    failed = {c.check for c in cross.failures}
    assert not cross.passed and cross.n_failed == 3
    assert failed == {"reference stepper: raster", "ONNX (onnxruntime): raster", "NIR read back: raster"}


def test_cross_implementation_catches_a_corrupted_export(model_and_spikes, tmp_path, monkeypatch):
    model, spikes = model_and_spikes
    real = TARGETS.get("nir").read

    def tampered(path):
        rebuilt = real(path)
        mantissa = rebuilt.weight_mantissa.copy()
        mantissa[np.unravel_index(mantissa.argmax(), mantissa.shape)] -= 1  # one weight one level lower
        return dataclasses.replace(rebuilt, weight_mantissa=mantissa)

    monkeypatch.setitem(TARGETS._entries, "nir", dataclasses.replace(TARGETS.get("nir"), read=tampered))
    run = IntegerNetwork(model).run(spikes, record=True)
    cross = cross_implementation(model, spikes, run, folder=tmp_path, targets=("nir",), reference_queries=0)
    failed = {c.check for c in cross.failures}
    assert "NIR read back: weight_mantissa" in failed and not cross.passed
    assert ConformanceResult.from_dict(cross.to_dict()) == cross


class Tampered:
    """A backend that computes the integer network and then moves one spike (and optionally a saturation)."""

    name = "tampered"

    def __init__(self, model, saturations=0):
        self.inner, self.extra = IntegerNetwork(model), saturations

    def run(self, spikes, *, record=False):
        run = self.inner.run(spikes, record=True)
        counts = run.counts.clone()
        counts[0, 0] += 1
        return SpikeRun(counts=counts, raster=run.raster, saturations=run.saturations + self.extra)


def test_conformance_harness_detects_a_tampered_backend(model_and_spikes, tmp_path):
    model, spikes = model_and_spikes
    extra = [Contender("tampered", "tampered", Tampered(model, saturations=1))]
    cross = cross_implementation(model, spikes, folder=tmp_path, targets=(), reference_queries=0, extra=extra)
    assert {c.check for c in cross.failures} == {"tampered: counts", "tampered: saturations"}
    assert {c.check for c in cross.comparisons} == {"tampered: raster", "tampered: counts", "tampered: saturations"}
    assert not cross.passed and cross.n_checks == 3


# ---------------------------------------------------------------- the whole run


def test_verify_checkpoint_schema(verified, tiny):
    run = verified.to_dict()
    json.dumps(run, allow_nan=False)  # plain JSON, no NaN
    assert VerifiedRun.from_dict(json.loads(json.dumps(run))) == verified  # the typed run round-trips
    assert [r["bits"] for r in run["bits"]] == [8, 2]
    assert run["n_queries"] == 20 and run["label"] == "tiny"
    assert {(r["strategy"], r["k"]) for r in run["float"]["metrics"]} == {
        ("standard", 1),
        ("weighted", 1),
        ("wprob", 1),
        ("wprob", 3),
    }
    for result in run["bits"]:
        assert set(result) >= {
            "quantisation",
            "cross_implementation",
            "spike_level",
            "decision_level",
            "metrics",
            "tolerance_checks",
            "pr_curves",
            "weight_levels",
            "passed",
        }
        assert result["cross_implementation"]["passed"], result["cross_implementation"]["checks"]
        assert set(result["cross_implementation"]) == {
            "checks",
            "passed",
            "n_checks",
            "n_failed",
            "n_exact",
            "n_identical",
            "n_tolerance",
            "n_within_tolerance",
            "reference_queries",
            "skipped",
            "files",
        }
        spike = result["spike_level"]
        assert 0 <= spike["winner_agreement"] <= 1 and len(spike["count_correlation"]) == 20
        assert spike["saturations"] >= 0 and spike["total_spikes"] == sum(spike["spikes_per_query"])
        decision = result["decision_level"]
        assert set(decision["top1_agreement"]) == {"standard", "weighted", "wprob"}
        assert set(decision["aggregated_agreement"]) == {"1", "3"}
        assert 0 <= decision["wprob_tv_mean"] <= decision["wprob_tv_max"] <= 1
        for row in result["metrics"]:
            for metric in ("accuracy", "r_at_100p"):
                assert row["delta"][metric] == pytest.approx(row[metric] - row["float"][metric])
        assert len(result["weight_levels"]["counts"]) == (1 << result["bits"])
    assert run["bits"][0]["spike_level"]["winner_agreement"] >= run["bits"][1]["spike_level"]["winner_agreement"]


def test_verify_is_deterministic_and_float_path_matches_evaluate(verified, tiny, tmp_path):
    from vprsnn_export.runtime.evaluation import evaluate_float

    path, ckpt, data = tiny
    options = VerifyOptions(
        readout=SequenceOptions(ks=(1, 3)),
        bits=(8,),
        targets=(),
        reference_queries=0,
    )
    again = verify_checkpoint(
        VerifiedNetwork(ckpt, checkpoint_sha256(path), {"summer": data.traversal("summer")}),
        Query("winter", data.traversal("winter"), data.place_ids),
        options,
    )
    assert again.bits[0].metrics == verified.bits[0].metrics
    evaluated = evaluate_float(
        ckpt, data.traversal("winter"), data.place_ids, "winter", options.readout, device=torch.device("cpu")
    )
    assert [r.to_dict() for r in again.float.metrics] == evaluated.rows


def test_verify_scores_and_aggregates_each_network_once(tiny, monkeypatch):
    """Issues 25, 33: the float network and each deployed width are scored by one Readout.scores call and
    aggregated once per k > 1 (the rows and the decision-level checks share the aggregates)."""
    from vprsnn_export.readout import sequence
    from vprsnn_export.readout.scoring import Readout

    path, ckpt, data = tiny
    scored, aggregated = [], []
    real_scores, real_aggregate = Readout.scores, sequence.aggregate
    monkeypatch.setattr(Readout, "scores", lambda *a, **kw: scored.append(1) or real_scores(*a, **kw))
    monkeypatch.setattr(sequence, "aggregate", lambda *a, **kw: aggregated.append(a[1]) or real_aggregate(*a, **kw))
    options = VerifyOptions(
        readout=SequenceOptions(ks=(1, 3)),
        bits=(8, 4),
        targets=(),
        reference_queries=0,
    )
    verify_checkpoint(
        VerifiedNetwork(ckpt, checkpoint_sha256(path), {"summer": data.traversal("summer")}),
        Query("winter", data.traversal("winter"), data.place_ids),
        options,
    )
    assert len(scored) == 3  # float, 8 and 4 bits
    assert aggregated == [3, 3, 3]  # k = 3 once per network (twice before: in decision_scores and score_rows)


def test_build_report_and_summary(verified):
    report = build_report([verified, verified], {"bits": [8, 2]}, command=["vprsnn-export", "verify"], seconds=1.0)
    data = report.to_dict()
    assert data["schema"] == SCHEMA and report.versions["torch"] == torch.__version__
    summary = summarise_runs(report.runs)
    assert summary.n_runs == 2 and [b.bits for b in summary.bits] == [8, 2]
    row = summary.bits[0].metrics[0]
    assert row.values["accuracy"].n == 2 and row.values["accuracy"].std == 0.0
    json.dumps(data, allow_nan=False)
    assert VerifyReport.from_dict(json.loads(json.dumps(data))) == report


# ---------------------------------------------------------------- ensembles of modules


def test_module_rows_score_each_region_on_its_own_queries():
    """Two modules of two places; the quantised decision is wrong on place 3 only, module 1's winner differs once."""
    regions = np.array([[0, 2], [2, 4]])
    ids = np.array([10, 11, 12, 13])
    right = np.eye(4)
    wrong = right.copy()
    wrong[3] = [0, 0, 1, 0]
    float_raster = torch.zeros((4, 2, 4), dtype=torch.bool)
    int_raster = float_raster.clone()
    int_raster[0, 1, 2] = True
    floats, deployed = scored(right, ids, {1: right, 3: right}), scored(wrong, ids, {1: wrong, 3: wrong})
    rows = module_rows(regions, 2, floats, deployed, float_raster, int_raster)
    assert [(r.first_place, r.last_place, r.n_queries) for r in rows] == [(10, 11, 2), (12, 13, 2)]
    assert [r.accuracy for r in rows] == [1.0, 0.5] and [r.float_accuracy_k for r in rows] == [1.0, 1.0]
    assert rows[1].delta_k == -0.5 and rows[0].winner_agreement == 1.0 and rows[1].winner_agreement == 7 / 8
    assert rows[1].spikes == 1 and rows[1].spikes_float == 0
    assert ModuleRow.from_dict(json.loads(json.dumps(rows[1].to_dict()))) == rows[1]


@pytest.mark.parametrize("budget", [None, 7 * 40 * 48])
def test_an_ensemble_is_verified_per_module_and_reported(tmp_path, monkeypatch, budget):
    verify_ensemble(tmp_path, monkeypatch, budget)


def verify_ensemble(tmp_path, monkeypatch, budget):
    """``budget``: rasters of 7 queries only (a whole route's would not fit in memory): same metrics."""
    if budget is not None:
        monkeypatch.setattr(verify_module, "RASTER_BUDGET", budget)
    cfg = Config().replace(
        **{"train.module_size": 10, "train.epochs": 2, "encoder.timesteps": 40, "network.n_neurons": 16}
    )
    data = load_dataset("synthetic:30", ["summer", "winter"], cfg.preprocess)
    ckpt = train_and_calibrate(data, ["summer"], cfg, progress=False)
    path = save_checkpoint(tmp_path / "ensemble.npz", ckpt)
    options = VerifyOptions(readout=SequenceOptions(ks=(1, 3)), bits=(8, 2), targets=())
    run = verify_checkpoint(
        VerifiedNetwork(ckpt, checkpoint_sha256(path), {"summer": data.traversal("summer")}, "ensemble"),
        Query("winter", data.traversal("winter"), data.place_ids),
        options,
    )
    recorded = 30 if budget is None else 7
    assert (run.recorded_queries, run.n_queries) == (recorded, 30)
    for result in run.bits:
        assert [(m.module, m.n_queries, m.k) for m in result.modules] == [(0, 10, 3), (1, 10, 3), (2, 10, 3)]
        assert all(0 <= m.winner_agreement <= 1 for m in result.modules)
        assert result.spike_level.n_steps == recorded * 40 and len(result.spike_level.spikes_per_query) == 30
        if budget is None:
            assert sum(m.spikes for m in result.modules) == result.spike_level.total_spikes
    assert VerifiedRun.from_dict(json.loads(json.dumps(run.to_dict()))).bits[1].modules == run.bits[1].modules
    report = build_report([run], {**options.to_dict(cfg), "query": "winter"}, command=["test"], seconds=1.0)
    written = write_report(report, tmp_path / "report")
    text = written["md"].read_text()
    assert "## Modules of the ensemble" in text and "modules.png" in text
    assert ("on the first 7 of 30 queries" in text) == (budget is not None)
    return run


def test_step_checks_on_the_first_queries_leave_the_metrics_alone(tmp_path, monkeypatch):
    whole = verify_ensemble(tmp_path / "a", monkeypatch, None)
    part = verify_ensemble(tmp_path / "b", monkeypatch, 7 * 40 * 48)
    assert whole.float.metrics == part.float.metrics
    for a, b in zip(whole.bits, part.bits, strict=True):
        assert a.metrics == b.metrics and a.spike_level.count_correlation == b.spike_level.count_correlation
        assert [m.accuracy_k for m in a.modules] == [m.accuracy_k for m in b.modules]


def test_a_tolerance_row_is_counted_on_its_own_with_its_measured_difference():
    from vprsnn_export.runtime.report.labels import cross_counts, tolerance_differences
    from vprsnn_export.runtime.results import Comparison, ConformanceResult

    exact = Comparison("ONNX: raster", "intsim", "onnx", "exact", True, "identical", 0, 10)
    row = Comparison(
        "NIR read back: snntorch + readout rule", "snntorch", "network", "decision agreement >= 95.0%", False,
        "98.0% of 100 decisions agree", n_differences=2, n_elements=100, tolerance=0.95,
    )  # fmt: skip
    below = dataclasses.replace(row, n_differences=6)
    assert not row.equal and row.passed and row.difference == 0.02 and not below.passed
    result = ConformanceResult((exact, row), reference_queries=1)
    data = result.to_dict()
    assert data["passed"] and (data["n_exact"], data["n_identical"], data["n_tolerance"]) == (1, 1, 1)
    assert data["checks"][1]["equal"] is False and data["checks"][1]["passed"] is True
    assert ConformanceResult.from_dict(data) == result
    assert cross_counts([result]) == "1/1 exact, 1/1 within tolerance"
    assert tolerance_differences(result) == "snntorch: 2.0 % of 100 decisions differ (limit 5.0 %)"
    assert not ConformanceResult((exact, below), reference_queries=1).passed
    older = {**data["checks"][1], "equal": True}  # files written before: no tolerance key, equal meant "passed"
    del older["tolerance"], older["passed"]
    assert Comparison.from_dict(older).tolerance == 0.95 and Comparison.from_dict(older).passed


def test_a_float_network_that_does_not_recognise_places_is_named_degenerate(verified):
    """Issue 45: R@100P = 0 at every k, or accuracy at k=1 within chance, is said in the verdict line and table."""
    import dataclasses

    from vprsnn_export.commands.verify import conclusion
    from vprsnn_export.runtime.report.labels import verdict_cells

    def with_float(accuracy: float, r_at_100p: float):
        rows = tuple(
            dataclasses.replace(row, values=dataclasses.replace(row.values, accuracy=accuracy, r_at_100p=r_at_100p))
            for row in verified.float.metrics
        )
        return dataclasses.replace(verified, float=dataclasses.replace(verified.float, metrics=rows))

    assert with_float(0.9, 0.5).degenerate is None
    assert "R@100P = 0 at every k" in with_float(0.9, 0.0).degenerate
    chance = 1 / len(verified.reference_place_ids)
    assert "within chance" in with_float(chance, 0.5).degenerate
    run = with_float(0.9, 0.0)
    report = build_report([run], {}, command=["verify"], seconds=1.0)
    line, code = conclusion(report, strict=False)
    assert "DEGENERATE float network" in line and code in (0, 1)
    assert all(verdict_cells("tiny", run, result)["verdict"].endswith("(degenerate float)") for result in run.bits)
    assert '"degenerate": "R@100P = 0' in json.dumps(run.to_dict())


def test_each_readout_column_is_decided_once_per_network_and_width(tiny, tmp_path, monkeypatch):
    """Issue 42: verify reads each side out once (a Scored) and compares them; W+Prob at k=1 is decided once for
    float and once per width, and nothing under runtime/verify decides a column again."""
    from vprsnn_export.readout import scored as scored_module
    from vprsnn_export.readout import stream

    path, ckpt, data = tiny
    calls: list[str] = []
    decide = scored_module.decide
    monkeypatch.setattr(
        scored_module, "decide", lambda matrix, strategy: calls.append(strategy) or decide(matrix, strategy)
    )
    monkeypatch.setattr(stream, "decide", lambda *_: pytest.fail("verify decided through a stream"))
    options = VerifyOptions(readout=SequenceOptions(ks=(1, 3)), bits=(8, 4), targets=(), reference_queries=1)
    run = verify_checkpoint(
        VerifiedNetwork(ckpt, checkpoint_sha256(path), {"summer": data.traversal("summer")}),
        Query("winter", data.traversal("winter"), data.place_ids),
        options,
        Runtime(export_dir=tmp_path),
    )
    networks = 1 + len(run.bits)  # float and each width
    assert calls.count("standard") == calls.count("weighted") == networks
    assert calls.count("wprob") == 2 * networks  # k=1 and k=3, once each
    assert run.bits[0].decision_level.top1_agreement["wprob"] >= 0  # the comparison read the same columns
