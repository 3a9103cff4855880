"""report.json through the generic dataclass <-> JSON mapping: every result type round-trips, and a
report written by the hand-written methods it replaced loads and is written back byte for byte."""

from __future__ import annotations

import copy
import dataclasses
import gzip
import json
from pathlib import Path

import pytest

from vprsnn_export.export.model import QuantisationReport
from vprsnn_export.runtime import results
from vprsnn_export.runtime.results import (
    Comparison,
    ConformanceResult,
    MetricRow,
    MetricValues,
    ReportError,
    ToleranceCheck,
    VerifiedRun,
    VerifyReport,
)
from vprsnn_export.stats import MeanStd

OLD_REPORT = Path(__file__).parent / "data" / "report_v1.json.gz"


@pytest.fixture(scope="module")
def old_json() -> dict:
    return json.loads(gzip.decompress(OLD_REPORT.read_bytes()))


def _instances(value, found):
    """Every dataclass instance inside a value, by type."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        found.setdefault(type(value), []).append(value)
        for item in dataclasses.fields(value):
            _instances(getattr(value, item.name), found)
    elif isinstance(value, dict):
        for item in value.values():
            _instances(item, found)
    elif isinstance(value, (tuple, list)):
        for item in value:
            _instances(item, found)
    return found


#: Keys computed from the fields and written since report_v1 (issue 32): the paired verdicts and the
#: exact / tolerance counts of the cross-implementation checks, a float consumer row's stated tolerance (read from
#: its kind). Everything else is written back as read.
ADDED_KEYS = {
    "verdict",
    "passed",
    "tolerance",
    "n_exact",
    "n_identical",
    "n_tolerance",
    "n_within_tolerance",
    "degenerate",
}


def _without_added(written, old):
    """``written`` without the keys it holds that ``old`` lacks (only those of ADDED_KEYS)."""
    if isinstance(written, dict) and isinstance(old, dict):
        extra = set(written) - set(old)
        assert extra <= ADDED_KEYS, extra
        return {k: _without_added(v, old[k]) for k, v in written.items() if k in old}
    if isinstance(written, list) and isinstance(old, list):
        return [_without_added(w, o) for w, o in zip(written, old, strict=True)]
    return written


def test_old_report_is_written_back_byte_for_byte(old_json):
    """...but a float consumer's row that compared nothing (the consumer refused the file), which report_v1
    marked ``equal: true`` for "passed", is written back ``equal: false`` (issue 32)."""
    report = VerifyReport.from_dict(old_json)
    written = report.to_dict()
    expected = copy.deepcopy(old_json)
    checks = [c for run in expected["runs"] for b in run["bits"] for c in b["cross_implementation"]["checks"]]
    refused = [c for c in checks if c["kind"].startswith("decision agreement") and c["n_elements"] is None]
    assert refused
    for row in refused:
        row["equal"] = False
    assert json.dumps(_without_added(written, old_json), indent=1) == json.dumps(expected, indent=1)
    assert written["verdict"] == ("holds" if old_json["passed"] else "fails")  # no paired table in an old file


def test_every_result_type_round_trips(old_json):
    found = _instances(VerifyReport.from_dict(old_json), {})
    result_types = {
        getattr(results, name) for name in results.__all__ if dataclasses.is_dataclass(getattr(results, name))
    }
    newer = {results.PairedCheck}  # written since report_v1: round-tripped below
    assert (result_types - newer) | {MeanStd, QuantisationReport} <= set(found)
    paired = results.PairedCheck("wprob", 3, "r_at_100p", 100, 4, 1, 0.5, -0.03, -0.12, 0.02, "block", limit=0.01)
    found[results.PairedCheck] = [paired, dataclasses.replace(paired, p_value=0.37, verdict="undecided", note="x")]
    for kind, values in found.items():
        for value in values:
            again = kind.from_dict(json.loads(json.dumps(value.to_dict())))
            assert again == value, kind.__name__


def test_comparison_families_keep_their_keys(old_json):
    checks = [c for run in old_json["runs"] for b in run["bits"] for c in b["cross_implementation"]["checks"]]
    families = {Comparison.from_dict(c).family: tuple(c) for c in checks}
    assert families == {
        "array": ("check", "a", "b", "kind", "equal", "n_elements", "n_differences", "first_difference", "detail"),
        "distribution": ("check", "a", "b", "kind", "equal", "max_abs_difference", "n_differences", "detail"),
        "config": ("check", "a", "b", "kind", "equal", "n_differences", "detail"),
    }


def test_metric_row_keys():
    values = MetricValues(0.5, 0.25, 0.125, 1.0)
    row = MetricRow("wprob", 3, values, 12)
    assert row.to_dict() == {"strategy": "wprob", "k": 3, **values.to_dict(), "n_queries": 12}
    quantised = MetricRow("wprob", 3, values, 12).with_float(MetricRow("wprob", 3, MetricValues(1, 1, 1, 1), 12))
    data = quantised.to_dict()
    assert list(data)[-2:] == ["float", "delta"] and data["delta"]["accuracy"] == -0.5
    assert MetricRow.from_dict(data) == quantised


def test_files_of_older_versions_load(old_json):
    """Keys older versions did not write take the values the hand-written readers gave them."""
    data = copy.deepcopy(old_json)
    run = data["runs"][0]
    for key in ("label", "seed", "config", "checkpoint_sha256", "checkpoint_data", "query_place_ids"):
        del run[key]
    for key in ("reference_place_ids", "export_dir", "checkpoint", "recorded_queries"):
        del run[key]
    bits = run["bits"][0]
    del bits["seconds"], bits["modules"]
    del bits["tolerance_checks"][0]["applied_limit"]
    del bits["spike_level"]["calibration_saturations"]
    del bits["cross_implementation"]["skipped"], bits["cross_implementation"]["files"]
    del data["created"], data["command"], data["seconds"], data["versions"]
    del data["summary"]["bits"][0]["winner_agreement"]["n"]
    report = VerifyReport.from_dict(data)
    loaded = report.runs[0]
    assert (loaded.label, loaded.seed, loaded.config, loaded.checkpoint_sha256) == (None, None, {}, "")
    assert (loaded.query_place_ids, loaded.export_dir, loaded.checkpoint, loaded.recorded_queries) == (
        (),
        None,
        None,
        None,
    )
    first = loaded.bits[0]
    assert first.seconds == {} and first.modules == ()
    assert first.tolerance_checks[0].applied_limit == first.tolerance_checks[0].limit
    assert first.spike_level.calibration_saturations is None
    assert first.cross_implementation.skipped == {} and first.cross_implementation.files == {}
    assert (report.created, report.command, report.seconds, report.versions) == ("?", None, None, {})
    assert report.summary.bits[0].winner_agreement.n == 0


@pytest.mark.parametrize(
    ("path", "value"),
    [
        (("runs", 0, "n_queries"), "many"),
        (("runs", 0, "bits", 0, "metrics"), {"a": 1}),
        (("runs", 0, "bits", 0, "spike_level", "count_correlation"), 3),
        (("runs", 0, "bits", 0, "decision_level", "aggregated_agreement"), {"three": 0.5}),
        (("summary",), None),
    ],
)
def test_malformed_values_are_one_report_error(old_json, path, value):
    data = copy.deepcopy(old_json)
    target = data
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    with pytest.raises(ReportError, match="malformed verify report") as caught:
        VerifyReport.from_dict(data, "x.json")
    assert ".".join(k for k in path if isinstance(k, str)) + ":" in str(caught.value)  # names the field


def test_missing_required_key_is_a_report_error(old_json):
    data = copy.deepcopy(old_json)
    del data["runs"][0]["bits"][0]["tolerance_checks"][0]["limit"]
    with pytest.raises(ReportError, match=r"\(runs\.bits\.tolerance_checks\.limit: missing\)"):
        VerifyReport.from_dict(data, "x.json")


def test_tolerance_check_and_conformance_keys():
    check = ToleranceCheck("accuracy", "drop", 0.1, 0.02, 0.05, False)
    assert list(check.to_dict()) == ["check", "what", "value", "limit", "applied_limit", "passed"]
    result = ConformanceResult((Comparison("x", "a", "b", "exact", True, "same", 0, 4, None),), 2)
    assert list(result.to_dict()) == [
        *("checks", "passed", "n_checks", "n_failed", "n_exact", "n_identical", "n_tolerance"),
        *("n_within_tolerance", "reference_queries", "skipped", "files"),
    ]
    assert ConformanceResult.from_dict(result.with_files("onnx", ["m.onnx"]).to_dict()).files == {"onnx": ("m.onnx",)}
    assert VerifiedRun.__dataclass_fields__["float"].name == "float"


def test_a_tolerance_row_never_claims_equality_it_did_not_measure(old_json):
    """Issue 32: a float consumer's tolerance row is ``equal`` only when it compared decisions, none differ and
    no raster entry differs; report_v1 wrote ``equal: true`` meaning "passed" (a consumer that refused the file
    included), and such a file still loads, with the row's equal corrected and everything else as written."""
    row = Comparison(
        "NIR read back: eulerlif + readout rule", "eulerlif", "network", "decision agreement >= 95.0%", True,
        "97.7% of 128 decisions agree (tolerance 95.0%); 2940 of 40960 raster entries differ after the rule",
        n_differences=3, n_elements=128, tolerance=0.95,
    )  # fmt: skip
    assert not row.equal and row.passed and row.to_dict()["equal"] is False
    raster_only = dataclasses.replace(row, equal=True, n_differences=0)
    assert not raster_only.equal and raster_only.passed  # decisions agree, 2940 raster entries do not
    agree = "100.0% of 128 decisions agree; 0 of 40960 raster entries differ after the rule"
    identical = dataclasses.replace(row, equal=True, n_differences=0, detail=agree)
    assert identical.equal
    refused = dataclasses.replace(
        row, equal=True, n_differences=None, n_elements=None, detail="not gated: the consumer refuses"
    )
    assert not refused.equal and refused.passed
    exact = Comparison("ONNX: raster", "intsim", "onnx", "exact", True, "identical", 0, 10)
    assert exact.equal  # an exact row keeps what it measured
    checks = [c for run in old_json["runs"] for b in run["bits"] for c in b["cross_implementation"]["checks"]]
    older = [c for c in checks if c["kind"].startswith("decision agreement")]
    assert older and all(c["equal"] for c in older)  # what report_v1 wrote
    loaded = [Comparison.from_dict(c) for c in older]
    assert [c.equal for c in loaded] == [c["n_differences"] == 0 for c in older]  # the refused rows: False
    assert not all(c.equal for c in loaded) and all(c.passed for c in loaded)
