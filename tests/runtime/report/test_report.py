"""report.json -> report.md / report.html, and several reports -> one with mean ± std."""

import base64
import html
import json
import re

import pytest

from vprsnn_export.cli import main
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.truth import Query
from vprsnn_export.errors import EXIT_BAD_INPUT
from vprsnn_export.io.checkpoint import checkpoint_sha256, load_checkpoint
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.report import combine_reports, load_report, write_report
from vprsnn_export.runtime.report.load import REPORT_JSON
from vprsnn_export.runtime.report.render import REPORT_HTML, REPORT_MD
from vprsnn_export.runtime.results import ReportError, VerifyReport
from vprsnn_export.runtime.verify import VerifiedNetwork, VerifyOptions, build_report, verify_checkpoint


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
        VerifiedNetwork(ckpt, checkpoint_sha256(path), {"summer": data.traversal("summer")}, "seed 42"),
        Query("winter", data.traversal("winter"), data.place_ids),
        options,
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
    assert f'<strong class="verdict-{report.verdict.upper()}">Verdict: {report.verdict.upper()}</strong>' in page
    assert f".verdict-{report.verdict.upper()} {{ color:" in page  # the verdict's colour


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


def test_combining_a_folded_or_non_leaky_report_needs_consent_and_an_older_report_is_neither(report):
    """Issue 33: verify --fold-thresholds / --non-leaky measure another deployment; a report written before these
    settings existed (no key) was neither, so it pools with a new default one."""
    older = json.loads(json.dumps(report.to_dict()))
    for key in ("fold_thresholds", "non_leaky"):
        assert report.settings[key] is False
        older["settings"].pop(key)
        other = json.loads(json.dumps(report.to_dict()))
        other["settings"][key] = True
        with pytest.raises(ReportError, match=f"differ in {key}"):
            combine_reports([report, VerifyReport.from_dict(other)])
    assert combine_reports([report, VerifyReport.from_dict(older)]).settings_differ == ()


# ---------------------------------------------------------------- issue 32: the report's columns, data and plots


def _edited(report, edit) -> VerifyReport:
    """The report with its JSON edited by ``edit(data)``, its summary recomputed from the edited runs."""
    data = json.loads(json.dumps(report.to_dict()))
    edit(data)
    return combine_reports([VerifyReport.from_dict(data)])


def _table(page: str, heading: str) -> tuple[list[str], list[list[str]]]:
    """The headers and the cells of the first HTML table after ``<h2>heading</h2>``."""
    table = page.split(f"<h2>{heading}</h2>", 1)[1].split("</table>", 1)[0]
    headers = [html.unescape(h) for h in re.findall(r"<th>(.*?)</th>", table)]
    rows = [
        [html.unescape(c) for c in re.findall(r"<td[^>]*>(.*?)</td>", row)]
        for row in re.findall(r"<tr[^>]*>(.*?)</tr>", table.split("<tbody>", 1)[1])
    ]
    return headers, rows


def test_the_terminal_and_the_html_show_the_same_verdict_columns(report, tmp_path):
    from vprsnn_export.commands.verify import verdict_rows
    from vprsnn_export.runtime.report.labels import VERDICT_COLUMNS
    from vprsnn_export.runtime.results import Comparison

    row = Comparison(
        "NIR read back: snntorch + readout rule", "snntorch", "network", "decision agreement >= 95.0%", False,
        "98.0% of 100 decisions agree", n_differences=2, n_elements=100, tolerance=0.95,
    )  # fmt: skip

    def add_tolerance_row(data):
        data["runs"][0]["bits"][0]["cross_implementation"]["checks"].append(row.to_dict())

    edited = _edited(report, add_tolerance_row)
    write_report(edited, tmp_path)
    headers, rows = _table((tmp_path / REPORT_HTML).read_text(), "Verdict per bit width")
    terminal = verdict_rows(edited)
    assert headers == [title for _, title in VERDICT_COLUMNS]
    assert rows == [[cells[key] for key, _ in VERDICT_COLUMNS] for cells in terminal]
    six, three = (r.cross_implementation for r in edited.runs[0].bits)
    n_exact = sum(
        "tolerance" not in c for c in report.to_dict()["runs"][0]["bits"][0]["cross_implementation"]["checks"]
    )
    assert six.n_exact == n_exact and six.n_tolerance == 1  # the tolerance row is not counted as exact
    assert [r["exact"] for r in terminal] == [f"{n_exact}/{n_exact}", f"{three.n_identical}/{three.n_exact}"]
    assert [r["tolerance"] for r in terminal] == ["1/1", "-"]
    headers, rows = _table((tmp_path / REPORT_HTML).read_text(), "Cross-implementation (exact)")
    assert headers[2:5] == ["exact rows identical", "tolerance rows within", "tolerance rows: decisions that differ"]
    assert rows[0][2:5] == [f"{n_exact}/{n_exact}", "1/1", "snntorch: 2.0 % of 100 decisions differ (limit 5.0 %)"]
    assert "within tolerance" not in (tmp_path / REPORT_MD).read_text().split("## Cross-implementation")[0]


def test_the_networks_table_names_the_data_evaluated_and_the_training_data(report, tmp_path):
    evaluated = _edited(report, lambda d: d["settings"].update(data="nordland:dev", places="100:50"))
    write_report(evaluated, tmp_path)
    headers, rows = _table((tmp_path / REPORT_HTML).read_text(), "Networks")
    cells = dict(zip(headers, rows[0], strict=True))
    assert cells["trained on"] == "synthetic:16 (all places)"
    assert cells["evaluated on"] == "nordland:dev (places 100:50), 'winter'"


def test_long_provenance_lines_wrap_in_html(report, tmp_path):
    long = _edited(report, lambda d: d.update(command=["vprsnn-export", "verify", "x" * 400]))
    write_report(long, tmp_path)
    page = (tmp_path / REPORT_HTML).read_text()
    style = re.search(r"<style>(.*?)</style>", page, re.S).group(1)
    pre = re.search(r"\bpre \{([^}]*)\}", style).group(1)
    assert "white-space: pre-wrap" in pre and "overflow-wrap: anywhere" in pre  # a 400-character line breaks
    assert "x" * 400 in page


@pytest.fixture
def figures(monkeypatch):
    """The matplotlib figures the report draws (still written as PNGs)."""
    from vprsnn_export.runtime.report import plots

    drawn, png = [], plots.png
    monkeypatch.setattr(plots, "png", lambda fig: drawn.append(fig) or png(fig))
    return drawn


def test_one_bit_width_is_drawn_as_bars_with_sensible_limits(report, tmp_path, figures):
    def keep_six(data):
        data["runs"][0]["bits"] = data["runs"][0]["bits"][:1]
        data["settings"]["bits"] = [6]

    one = _edited(report, keep_six)
    write_report(one, tmp_path)
    metrics, _, spikes, _ = figures  # metrics, PR curves, spike agreement, weights
    for ax in metrics.axes:  # per readout, float and 6-bit side by side, not a dot at x = 6 on an axis 5.5..6.5
        heights = [bar.get_height() for bar in ax.patches]
        assert len(heights) == 2 * 4 and ax.get_xlim()[1] - ax.get_xlim()[0] < 5
        assert max(heights) <= ax.get_ylim()[1] <= max(5.0, 1.15 * max(heights)) + 1e-9
        assert [t.get_text() for t in ax.get_legend().get_texts()] == ["float", "6-bit"]
    assert len(spikes.axes[0].patches) == 3 and spikes.axes[0].get_xlabel() == "6-bit"
    assert (tmp_path / "plots" / "metrics_vs_bits.png").read_bytes().startswith(b"\x89PNG")


def test_a_series_hidden_under_an_identical_one_is_labelled_a_equals_b(report, tmp_path, figures):
    def weighted_is_wprob(data):
        run = data["runs"][0]
        for rows in [run["float"]["metrics"], *(r["metrics"] for r in run["bits"])]:
            by_key = {(row["strategy"], row["k"]): row for row in rows}
            by_key[("weighted", 1)].update({k: v for k, v in by_key[("wprob", 1)].items() if k != "strategy"})
        run["bits"][0]["pr_curves"] = run["float"]["pr_curves"]  # 6 bits: the float network's curves

    same = _edited(report, weighted_is_wprob)
    write_report(same, tmp_path)
    metrics, pr, _, _ = figures
    for ax in metrics.axes:
        labels = [t.get_text() for t in ax.get_legend().get_texts()]
        named = [name for label in labels for name in label.split(" = ")]  # each readout named once
        assert any("Weighted k=1 = W+Prob k=1" in label for label in labels) and len(named) == len(set(named)) == 4
    for ax in pr.axes:
        assert [t.get_text() for t in ax.get_legend().get_texts()] == ["float = 6-bit", "3-bit"]
