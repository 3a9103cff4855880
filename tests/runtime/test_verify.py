"""The verification checks: pure functions on small arrays, then the whole run on a tiny trained network."""

import json

import numpy as np
import pytest
import torch

from vprsnn_export.checkpoint import checkpoint_sha256, load_checkpoint
from vprsnn_export.cli import main
from vprsnn_export.dataset import load_dataset
from vprsnn_export.errors import EXIT_BAD_INPUT, InvalidValueError
from vprsnn_export.runtime.evaluation import ReadoutOptions, evaluate_float
from vprsnn_export.runtime.verify import (
    DEFAULT_TOLERANCES,
    SCHEMA,
    VerifyOptions,
    build_report,
    count_correlations,
    metric_deltas,
    parse_tolerances,
    summarise_runs,
    tolerance_checks,
    top1_agreement,
    tv_distance,
    verify_checkpoint,
)

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
    options = VerifyOptions(
        readout=ReadoutOptions(gamma=ckpt.config.assignment.gamma, ks=(1, 3)), bits=(8, 2), reference_queries=2
    )
    run = verify_checkpoint(
        ckpt,
        checkpoint_sha256(path),
        data.traversal("winter"),
        data.place_ids,
        "winter",
        options,
        reference_images={"summer": data.traversal("summer")},
        export_dir=tmp_path_factory.mktemp("exports"),
        label="tiny",
    )
    return run


# ---------------------------------------------------------------- options


def test_tolerances_default_override_and_off():
    assert parse_tolerances(None) == DEFAULT_TOLERANCES
    tol = parse_tolerances("r_at_100p=0.05, accuracy=off,winner_agreement=0.9")
    assert tol["r_at_100p"] == 0.05 and tol["accuracy"] is None and tol["winner_agreement"] == 0.9
    assert tol["auc_pr"] is None and tol["query_slack"] == DEFAULT_TOLERANCES["query_slack"]


@pytest.mark.parametrize("bad", ["nonsense=1", "accuracy", "accuracy=abc", "accuracy=-0.1", "r_at_100p=nan"])
def test_bad_tolerances_are_option_errors(bad):
    with pytest.raises(InvalidValueError) as info:
        parse_tolerances(bad)
    assert info.value.exit_code == EXIT_BAD_INPUT


# ---------------------------------------------------------------- spike and decision level


def test_count_correlations():
    a = np.array([[0, 1, 2, 3], [0, 0, 0, 0], [0, 0, 0, 0], [1, 2, 3, 4]])
    b = np.array([[0, 2, 4, 6], [0, 0, 0, 0], [0, 1, 0, 0], [4, 3, 2, 1]])
    np.testing.assert_allclose(count_correlations(a, b), [1.0, 1.0, 0.0, -1.0])


def test_tv_distance_and_top1_agreement():
    p = np.array([[0.5, 0.5, 0.0], [1.0, 0.0, 0.0]])
    q = np.array([[0.5, 0.5, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(tv_distance(p, q), [0.0, 1.0])
    assert top1_agreement(p, q, "wprob") == 0.5
    flat = np.full((2, 3), 1 / 3)
    assert top1_agreement(flat, flat, "wprob") == 1.0  # both no-match: the same decision


def _rows(float_values, quant_values, n=50):
    def rows(values):
        return [
            {"strategy": s, "k": k, "accuracy": v, "p_at_100r": v, "r_at_100p": v, "auc_pr": v, "n_queries": n}
            for (s, k), v in zip([("standard", 1), ("weighted", 1), ("wprob", 1), ("wprob", 5)], values, strict=True)
        ]

    return metric_deltas(rows(float_values), rows(quant_values))


def test_tolerance_checks_bound_drops_only():
    tol = parse_tolerances("query_slack=0")
    spike, decision = {"winner_agreement": 0.9, "saturations": 0}, {"top1_agreement": {"wprob": 0.8}}
    better = tolerance_checks(_rows([0.5] * 4, [0.9] * 4), spike, decision, tol, (1, 5))
    assert better and all(c["passed"] for c in better)
    worse = tolerance_checks(_rows([0.5, 0.5, 0.5, 0.8], [0.49, 0.5, 0.5, 0.78]), spike, decision, tol, (1, 5))
    verdicts = {c["what"]: c["passed"] for c in worse}
    assert verdicts["accuracy drop, standard k=1"] is True  # 1 point <= 2 points
    assert verdicts["r_at_100p drop, wprob k=5"] is False  # 2 points > 1 point
    strict = tolerance_checks(
        _rows([0.5] * 4, [0.5] * 4),
        spike,
        decision,
        parse_tolerances("winner_agreement=0.95,top1_agreement=0.8,saturations=0"),
        (1, 5),
    )
    assert {
        c["check"]: c["passed"] for c in strict if c["check"] in ("winner_agreement", "top1_agreement", "saturations")
    } == {"winner_agreement": False, "top1_agreement": True, "saturations": True}


def test_query_slack_allows_one_query_of_a_short_route():
    rows = _rows([0.5, 0.5, 0.5, 0.8], [0.5, 0.5, 0.5, 0.8 - 1 / 30], n=30)
    spike, decision = {"winner_agreement": 1.0, "saturations": 0}, {"top1_agreement": {"wprob": 1.0}}
    one = {c["what"]: c for c in tolerance_checks(rows, spike, decision, parse_tolerances(None), (1, 5))}
    assert one["r_at_100p drop, wprob k=5"]["passed"] and one["r_at_100p drop, wprob k=5"][
        "applied_limit"
    ] == pytest.approx(1 / 30)
    none = {c["what"]: c for c in tolerance_checks(rows, spike, decision, parse_tolerances("query_slack=0"), (1, 5))}
    assert not none["r_at_100p drop, wprob k=5"]["passed"]


# ---------------------------------------------------------------- cross-implementation on a real model


# ---------------------------------------------------------------- the whole run


def test_verify_checkpoint_schema(verified, tiny):
    run = verified
    json.dumps(run, allow_nan=False)  # plain JSON, no NaN
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

    path, ckpt, data = tiny
    options = VerifyOptions(
        readout=ReadoutOptions(gamma=ckpt.config.assignment.gamma, ks=(1, 3)),
        bits=(8,),
        targets=(),
        reference_queries=0,
    )
    again = verify_checkpoint(
        ckpt,
        checkpoint_sha256(path),
        data.traversal("winter"),
        data.place_ids,
        "winter",
        options,
        reference_images={"summer": data.traversal("summer")},
    )
    assert again["bits"][0]["metrics"] == verified["bits"][0]["metrics"]
    evaluated = evaluate_float(
        ckpt, data.traversal("winter"), data.place_ids, "winter", options.readout, device=torch.device("cpu")
    )
    assert again["float"]["metrics"] == evaluated.rows


def test_build_report_and_summary(verified):
    report = build_report([verified, verified], {"bits": [8, 2]}, command=["vprsnn-export", "verify"], seconds=1.0)
    assert report["schema"] == SCHEMA and report["versions"]["torch"] == torch.__version__
    summary = summarise_runs(report["runs"])
    assert summary["n_runs"] == 2 and [b["bits"] for b in summary["bits"]] == [8, 2]
    row = summary["bits"][0]["metrics"][0]
    assert row["accuracy"]["n"] == 2 and row["accuracy"]["std"] == 0.0
    json.dumps(report, allow_nan=False)
