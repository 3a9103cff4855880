"""report.json -> report.md / report.html, and several reports -> one with mean ± std."""

import base64
import json
import re

import pytest

from vprsnn_export.cli import main
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.errors import EXIT_BAD_INPUT
from vprsnn_export.io.checkpoint import checkpoint_sha256, load_checkpoint
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.report import combine_reports, load_report, write_report
from vprsnn_export.runtime.report.load import REPORT_JSON
from vprsnn_export.runtime.report.render import REPORT_HTML, REPORT_MD
from vprsnn_export.runtime.results import ReportError, VerifyReport
from vprsnn_export.runtime.verify import VerifyOptions, build_report, verify_checkpoint


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    folder = tmp_path_factory.mktemp("report")
    path = folder / "net.npz"
    assert (
        main(
            [
                "train",
                "--data",
                "synthetic:16",
                "--reference",
                "summer",
                "--out",
                str(path),
                "--quiet",
                "--timesteps",
                "30",
                "--epochs",
                "1",
                "--neurons",
                "32",
            ]
        )
        == 0
    )
    ckpt = load_checkpoint(path)
    data = load_dataset("synthetic:16", ["summer", "winter"], ckpt.config.preprocess)
    options = VerifyOptions(
        readout=SequenceOptions(ks=(1, 3)),
        bits=(6, 3),
        targets=("onnx",),
        reference_queries=1,
    )
    run = verify_checkpoint(
        ckpt,
        checkpoint_sha256(path),
        data.traversal("winter"),
        data.place_ids,
        "winter",
        options,
        reference_images={"summer": data.traversal("summer")},
        label="seed 42",
    )
    return build_report(
        [run], {**options.to_dict(ckpt.config), "query": "winter"}, command=["vprsnn-export", "verify", str(path)]
    )


def test_writes_json_markdown_and_self_contained_html(report, tmp_path):
    written = write_report(report, tmp_path)
    assert set(written) == {"json", "md", "html"}
    assert json.loads((tmp_path / REPORT_JSON).read_text()) == json.loads(json.dumps(report.to_dict()))
    md = (tmp_path / REPORT_MD).read_text()
    for heading in (
        "Verdict per bit width",
        "Paired verdict",
        "Metric level",
        "Spike level",
        "Decision level",
        "Cross-implementation (exact)",
        "Quantisation",
        "Tolerance checks",
        "Provenance",
    ):
        assert f"## {heading}" in md
    for image in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", md):
        assert (tmp_path / image).is_file()
    page = (tmp_path / REPORT_HTML).read_text()
    assert page.startswith("<!DOCTYPE html>") and page.rstrip().endswith("</html>")
    assert not re.search(r"""(src|href)=["'](?!data:)""", page), "the HTML must not load anything from outside"
    images = re.findall(r'src="data:image/png;base64,([^"]+)"', page)
    assert len(images) == 4
    for data in images:
        assert base64.b64decode(data).startswith(b"\x89PNG")
    assert "6-bit" in page and "3-bit" in page and "W+Prob k=3" in page


def test_report_rebuilds_from_json_alone(report, tmp_path):
    write_report(report, tmp_path)
    (tmp_path / REPORT_MD).unlink()
    (tmp_path / REPORT_HTML).unlink()
    assert main(["report", str(tmp_path), "--quiet"]) == 0
    assert (tmp_path / REPORT_MD).is_file() and (tmp_path / REPORT_HTML).is_file()
    assert load_report(tmp_path).runs == report.runs
    assert load_report(tmp_path).to_dict() == json.loads(json.dumps(report.to_dict()))


def test_combining_runs_gives_mean_and_std(report, tmp_path):
    second = json.loads(json.dumps(report.to_dict()))
    for result in second["runs"][0]["bits"]:  # a second "network" whose 3-bit accuracy is 10 points apart
        for row in result["metrics"]:
            if result["bits"] == 3:
                shift = 0.1 if row["accuracy"] <= 0.9 else -0.1  # an accuracy stays in [0, 1]
                row["accuracy"] += shift
                row["delta"]["accuracy"] += shift
    combined = combine_reports([report, VerifyReport.from_dict(second)], ["a", "b"])
    assert combined.summary.n_runs == 2 and combined.to_dict()["combined_from"] == ["a", "b"]
    by_bits = {b.bits: b for b in combined.summary.bits}
    acc = by_bits[3].metrics[0].values["accuracy"]
    assert acc.n == 2 and acc.std == pytest.approx(0.1 / 2**0.5)
    assert by_bits[6].metrics[0].values["accuracy"].std == 0.0
    assert VerifyReport.from_dict(combined.to_dict()) == combined
    write_report(combined, tmp_path)
    assert "±" in (tmp_path / REPORT_MD).read_text()


def test_report_command_combines_folders(report, tmp_path):
    write_report(report, tmp_path / "a")
    write_report(report, tmp_path / "b")
    assert (
        main(
            [
                "report",
                str(tmp_path / "a"),
                str(tmp_path / "b" / REPORT_JSON),
                "--out",
                str(tmp_path / "both"),
                "--quiet",
            ]
        )
        == 0
    )
    assert len(load_report(tmp_path / "both").runs) == 2
    assert main(["report", str(tmp_path / "a"), str(tmp_path / "b"), "--quiet"]) == EXIT_BAD_INPUT  # needs --out


def test_bad_report_files(tmp_path):
    with pytest.raises(ReportError):
        load_report(tmp_path)
    (tmp_path / REPORT_JSON).write_text("{not json")
    with pytest.raises(ReportError):
        load_report(tmp_path)
    (tmp_path / REPORT_JSON).write_text(json.dumps({"schema": "something else"}))
    with pytest.raises(ReportError):
        load_report(tmp_path)
    (tmp_path / REPORT_JSON).write_text(json.dumps({"schema": "vprsnn-verify-report/1", "runs": [{"query": "x"}]}))
    with pytest.raises(ReportError, match="malformed"):
        load_report(tmp_path)
    assert main(["report", str(tmp_path)]) == EXIT_BAD_INPUT


def test_combining_reports_of_other_data_or_bits_needs_consent(report):
    other = json.loads(json.dumps(report.to_dict()))
    other["settings"]["bits"] = [8]
    with pytest.raises(ReportError, match="differ in bits"):
        combine_reports([report, VerifyReport.from_dict(other)])
    combined = combine_reports([report, VerifyReport.from_dict(other)], allow_mixed=True)
    assert combined.settings_differ == ("bits",)
