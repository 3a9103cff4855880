"""`vprsnn-export verify` through the CLI: exit codes 0 / 1 / 2, report.json schema, --seeds."""

import json

import numpy as np
import pytest

from vprsnn_export.cli import main
from vprsnn_export.commands.verify import EXIT_UNDECIDED, conclusion
from vprsnn_export.errors import EXIT_BAD_INPUT, EXIT_CHECK_FAILED
from vprsnn_export.export.model import load_fixed_point
from vprsnn_export.runtime.results import VerifyReport

TINY = ["--timesteps", "40", "--epochs", "2", "--neurons", "48"]
LENIENT = "accuracy=1,r_at_100p=1"


@pytest.fixture(scope="module")
def checkpoint(cli_checkpoint):
    """A 48-neuron network on 20 synthetic places, trained once per session (tests/conftest.py)."""
    return cli_checkpoint("synthetic:20", "--quiet", *TINY)


def verify(checkpoint, report, *extra):
    return main(
        [
            "verify",
            str(checkpoint),
            "--query",
            "winter",
            "--k",
            "1,3",
            "--report",
            str(report),
            "--reference-queries",
            "1",
            "--quiet",
            *extra,
        ]
    )


@pytest.fixture(scope="module")
def passed(checkpoint, tmp_path_factory):
    report = tmp_path_factory.mktemp("passed")
    code = verify(checkpoint, report, "--bits", "8,3", "--tolerance", LENIENT)
    return code, report


def test_lenient_tolerances_pass_with_exit_0(passed):
    code, report = passed
    assert code == 0
    for name in ("report.json", "report.md", "report.html"):
        assert (report / name).is_file()


def test_report_json_schema(passed, checkpoint):
    _, report = passed
    data = json.loads((report / "report.json").read_text())
    assert data["schema"] == "vprsnn-verify-report/1" and data["passed"] is True
    assert set(data) >= {"created", "command", "versions", "settings", "runs", "summary"}
    assert data["settings"]["bits"] == [8, 3] and data["settings"]["tolerances"]["accuracy"] == 1.0
    assert data["settings"]["per_neuron"] is True and data["settings"]["query"] == "winter"
    assert data["command"][:3] == ["vprsnn-export", "verify", str(checkpoint)]
    assert {"torch", "numpy", "onnx", "onnxruntime", "nir"} <= set(data["versions"])
    (run,) = data["runs"]
    assert run["config"]["encoder"]["timesteps"] == 40 and run["checkpoint"] == str(checkpoint)
    assert [r["bits"] for r in run["bits"]] == [8, 3]
    assert run["float"]["cost"]["steps"] == 40 and run["float"]["cost"]["synaptic_events"] > 0
    for result in run["bits"]:
        cross = result["cross_implementation"]
        assert cross["passed"] and cross["reference_queries"] == 1
        assert set(cross["files"]) == {"onnx", "nir", "loihi", "model"}
        exact = [c for c in cross["checks"] if "tolerance" not in c]
        assert all(c["equal"] and c["passed"] for c in exact) and cross["n_identical"] == cross["n_exact"] == len(exact)
        for row in (c for c in cross["checks"] if "tolerance" in c):  # a float consumer: never counted as exact
            assert row["passed"] and (not row["equal"] or row.get("n_differences") == 0)
            parts = row["detail"].split("; ")  # "...decisions agree...; N of M raster entries differ...; ..."
            identical = len(parts) > 1 and parts[1].startswith("0 of ") and row.get("n_differences") == 0
            assert row["equal"] is identical
        assert cross["n_exact"] + cross["n_tolerance"] == cross["n_checks"]
    assert [b["bits"] for b in data["summary"]["bits"]] == [8, 3]


def test_paired_table_in_json_and_markdown(passed):
    _, report = passed
    data = json.loads((report / "report.json").read_text())
    assert data["verdict"] == "holds" and data["settings"]["statistics"] == {
        "confidence": 0.95,
        "resamples": 2000,
        "seed": 0,
    }
    for result in data["runs"][0]["bits"]:
        paired = {(c["strategy"], c["k"], c["metric"]): c for c in result["paired"]}
        assert {"float_right_deployed_wrong", "float_wrong_deployed_right", "low", "high"} <= set(
            paired[("wprob", 3, "accuracy")]
        )
        assert paired[("standard", 1, "accuracy")]["method"] == "exact McNemar"
        assert paired[("wprob", 3, "r_at_100p")]["method"] == "paired block bootstrap (blocks of 3)"
        assert result["verdict"] == "holds"
    md = (report / "report.md").read_text()
    assert "## Paired verdict" in md and "flips -/+" in md


def test_undecided_exits_0_and_3_with_strict(passed):
    _, folder = passed
    data = json.loads((folder / "report.json").read_text())
    check = next(c for c in data["runs"][0]["bits"][0]["paired"] if c["verdict"] == "holds")
    check.update(verdict="undecided", queries_to_decide=400)
    report = VerifyReport.from_dict(data)
    assert report.verdict == "undecided" and report.passed
    line, code = conclusion(report, strict=False)
    assert code == 0 and line.startswith("UNDECIDED") and "about 400 queries" in line
    assert conclusion(report, strict=True)[1] == EXIT_UNDECIDED


def test_the_exit_code_follows_the_reported_verdict(checkpoint, tmp_path, capsys):
    code = verify(checkpoint, tmp_path, "--bits", "2", "--targets", "none", "--strict")
    out = capsys.readouterr().out
    verdict = json.loads((tmp_path / "report.json").read_text())["verdict"]
    assert code == {"holds": 0, "undecided": EXIT_UNDECIDED, "fails": EXIT_CHECK_FAILED}[verdict]
    assert out.splitlines()[-1].startswith(verdict.upper()) and "flips -/+" in out


def test_impossible_tolerance_exits_1(checkpoint, tmp_path, capsys):
    assert (
        verify(checkpoint, tmp_path, "--bits", "2", "--tolerance", "winner_agreement=1.0", "--targets", "none")
        == EXIT_CHECK_FAILED
    )
    out = capsys.readouterr().out
    assert "FAILS" in out and "report.html" in out
    data = json.loads((tmp_path / "report.json").read_text())
    checks = data["runs"][0]["bits"][0]["tolerance_checks"]
    assert any(c["check"] == "winner_agreement" and not c["passed"] for c in checks)


@pytest.mark.parametrize(
    "extra",
    [
        ["--bits", "9"],
        ["--bits", "1,8"],
        ["--bits", "eight"],
        ["--tolerance", "speed=1"],
        ["--tolerance", "accuracy=-1"],
        ["--targets", "tflite"],
        ["--k", "0"],
        ["--reference-queries", "-1"],
        ["--query", "autumn"],
    ],
)
def test_bad_input_exits_2(checkpoint, tmp_path, extra):
    assert verify(checkpoint, tmp_path, *extra) == EXIT_BAD_INPUT


def test_missing_checkpoint_and_bad_seed_use_exit_2(checkpoint, tmp_path):
    assert verify(tmp_path / "absent.npz", tmp_path) == EXIT_BAD_INPUT
    assert (
        main(
            [
                "verify",
                str(checkpoint),
                str(checkpoint),
                "--seeds",
                "2",
                "--query",
                "winter",
                "--report",
                str(tmp_path),
                "--quiet",
            ]
        )
        == EXIT_BAD_INPUT
    )


def test_json_output(checkpoint, tmp_path, capsys):
    assert verify(checkpoint, tmp_path, "--bits", "8", "--tolerance", LENIENT, "--targets", "none", "--json") == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["passed"] is True and payload["report"]["html"].endswith("report.html")
    assert payload["summary"]["bits"][0]["bits"] == 8


def test_seeds_train_independent_networks(checkpoint, tmp_path, monkeypatch):
    monkeypatch.setenv("VPRSNN_CACHE", str(tmp_path / "cache"))
    report = tmp_path / "seeds"
    code = verify(checkpoint, report, "--bits", "8", "--seeds", "2", "--tolerance", LENIENT, "--targets", "onnx")
    assert code == 0
    data = json.loads((report / "report.json").read_text())
    assert [run["seed"] for run in data["runs"]] == [1, 2]
    assert data["runs"][0]["checkpoint_sha256"] != data["runs"][1]["checkpoint_sha256"]
    assert data["summary"]["n_runs"] == 2 and data["summary"]["bits"][0]["metrics"][0]["accuracy"]["n"] == 2
    assert (report / "checkpoints" / "seed1.npz").is_file() and (report / "checkpoints" / "seed2.npz").is_file()
    assert not (tmp_path / "cache").exists()  # the experiments' cache is the lab's: verify trains its own
    assert "±" in (report / "report.md").read_text()


@pytest.mark.parametrize("flag", ["--fold-thresholds", "--non-leaky"])
def test_verify_checks_a_folded_or_non_leaky_deployment(checkpoint, tmp_path, flag):
    """Issue 33: verify takes quantize's flags; the deployment it checks is the one quantize writes with the flag,
    every implementation agrees exactly on it, and the report names the options."""
    code = verify(checkpoint, tmp_path, "--bits", "4", "--tolerance", LENIENT, flag)
    assert code in (0, EXIT_CHECK_FAILED)  # a check may fail against float; the deployment was verified
    data = json.loads((tmp_path / "report.json").read_text())
    given = flag[2:].replace("-", "_")
    options = {key: data["settings"][key] for key in ("fold_thresholds", "non_leaky", "per_neuron", "calibration")}
    assert options == {"fold_thresholds": False, "non_leaky": False, "per_neuron": True, "calibration": "deployed"} | {
        given: True
    }
    (result,) = data["runs"][0]["bits"]
    assert result["cross_implementation"]["passed"] and result["quantisation"]["calibration"].startswith("deployed")
    model = load_fixed_point(next((tmp_path / "exports").glob("*/4bit/model.npz")))
    quantized = tmp_path / "q"
    assert main(["quantize", str(checkpoint), "--bits", "4", flag, "--out", str(quantized), "--quiet"]) == 0
    written = load_fixed_point(next(quantized.glob("model_4bit_*.npz")))
    assert np.array_equal(model.threshold, written.threshold) and model.decay_dv == written.decay_dv
    if given == "non_leaky":
        assert model.decay_dv == 0 and model.config.network.beta == 1.0
    else:
        assert result["quantisation"]["threshold_folding"] and len(set(model.threshold.tolist())) == 1
    assert f'"{given}": true' in (tmp_path / "report.md").read_text()


def test_verify_refuses_a_non_leaky_deployment_with_the_float_calibration(checkpoint, tmp_path, capsys):
    assert verify(checkpoint, tmp_path, "--non-leaky", "--reuse-float-calibration") == EXIT_BAD_INPUT
    assert "non_leaky (--non-leaky) needs the deployed calibration" in capsys.readouterr().err
