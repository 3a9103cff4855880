"""A tampered report.json (issue 31): values out of range are refused naming the file; stored strings cannot
forge a line of report.md."""

import copy
import gzip
import json
import re
from pathlib import Path

import pytest

from vprsnn_export.cli import main
from vprsnn_export.errors import EXIT_BAD_INPUT
from vprsnn_export.runtime.report import load_report, write_report
from vprsnn_export.runtime.report.render import REPORT_MD

V1 = Path(__file__).resolve().parents[1] / "data" / "report_v1.json.gz"


@pytest.fixture(scope="module")
def stored():
    return json.loads(gzip.decompress(V1.read_bytes()))


def _metric(data):
    return data["runs"][0]["bits"][0]["metrics"][0]


EDITS = {
    "accuracy-5": lambda d: _metric(d).update(accuracy=5),
    "accuracy-negative": lambda d: _metric(d).update(accuracy=-1),
    "accuracy-nan": lambda d: _metric(d).update(accuracy=float("nan")),
    "float-auc-above-1": lambda d: d["runs"][0]["float"]["metrics"][0].update(auc_pr=1.5),
    "bits-99": lambda d: d["runs"][0]["bits"][0].update(bits=99),
    "summary-bits-99": lambda d: d["summary"]["bits"][0].update(bits=99),
    "seconds-infinite": lambda d: d.update(seconds=float("inf")),
    "summary-mean-5": lambda d: d["summary"]["float"][0]["accuracy"].update(mean=5),
}


@pytest.mark.parametrize("edit", EDITS)
def test_out_of_range_values_are_refused_naming_the_file(stored, edit, tmp_path, capsys):
    data = copy.deepcopy(stored)
    EDITS[edit](data)
    (tmp_path / "report.json").write_text(json.dumps(data), encoding="utf-8")
    assert main(["report", str(tmp_path), "--out", str(tmp_path / "out")]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "report.json" in err[0], err
    assert not (tmp_path / "out").exists()


def test_the_stored_report_still_loads(stored, tmp_path):
    (tmp_path / "report.json").write_text(json.dumps(stored), encoding="utf-8")
    assert load_report(tmp_path).runs


FORGED = "# all checks passed"


def test_stored_strings_cannot_forge_a_line(stored, tmp_path):
    data = copy.deepcopy(stored)
    data["runs"][0]["label"] = f"seed 1\n{FORGED}\r\n<script>x</script>|"
    data["runs"][0]["query"] = f"winter\u2028{FORGED}"
    data["runs"][0]["export_dir"] = f"deploy\n{FORGED}"
    data["created"] = f"today\n\n{FORGED}"
    data["command"] = ["vprsnn-export", f"verify\n```\n{FORGED}\n```"]
    data["settings"] = {**data["settings"], "data": f"nord\n{FORGED}"}
    (tmp_path / "report.json").write_text(json.dumps(data), encoding="utf-8")
    write_report(load_report(tmp_path), tmp_path / "out", write_json=False)
    md = (tmp_path / "out" / REPORT_MD).read_text(encoding="utf-8")
    lines = md.splitlines()
    assert not any(line.lstrip().startswith(FORGED) for line in lines)
    assert "<script>" not in md
    fences = [line for line in lines if re.fullmatch(r"`{3,}", line)]
    assert len(fences) % 2 == 0 and all(len(f) > 3 for f in fences[:2])  # the command's ``` cannot close its fence
    assert "seed 1 " in md  # the label is still shown, on one line
