"""`vprsnn-export demo`: the whole chain (train, quantise, export, verify, report), tiny with --quick."""

import json
import shlex

from vprsnn_export.cli import main
from vprsnn_export.commands.demo import DEMO_BITS
from vprsnn_export.export.model import load_fixed_point
from vprsnn_export.targets.loihi_target import read_loihi_model
from vprsnn_export.targets.nir_read import read_nir
from vprsnn_export.targets.onnx_session import read_onnx


def test_quick_demo_runs_the_whole_chain(tmp_path, capsys):
    out = tmp_path / "demo"
    code = main(["demo", "--quick", "--out", str(out), "--quiet"])
    printed = capsys.readouterr().out.strip().splitlines()
    assert printed[-2].startswith("report: ") and printed[-2].endswith("report.html")
    stored = json.loads((out / "report" / "report.json").read_text())
    verdict = stored["verdict"]
    exact = all(r["cross_implementation"]["passed"] for r in stored["runs"][0]["bits"])
    assert code == (0 if exact else 1)  # a width that fails is a finding: the demo exits 0 when it ran as intended
    assert printed[-1].startswith(f"Verdict: {verdict.upper()} ") and printed[-1].endswith(
        "exit code 0: the demo ran as intended; a width that fails is a finding"
    )
    html = (out / "report" / "report.html").read_text()
    assert f"Verdict: {verdict.upper()}" in html
    # the first line says what to conclude, naming every width with its verdict
    widths = {r["bits"]: r["verdict"] for r in stored["runs"][0]["bits"]}
    assert printed[0].startswith("Conclusion: ") and sorted(widths) == sorted(DEMO_BITS) == [2, 4, 8]
    for bits, width_verdict in widths.items():
        table = printed[printed.index("quantised and deployed vs float, on the same input spikes:") :]
        row = next(line.split() for line in table if line.split()[:1] == [str(bits)])
        assert row[1] == width_verdict.split()[0]
        named = next(part for part in printed[0].split(", ") if part.split(" bits ")[-1].startswith(width_verdict))
        assert str(bits) in named.split(" bits ")[0].split(" ")[-1].split("/")
        # the line under the conclusion names the check that decides the width, with its interval in points
        decided = next(line for line in printed[1:4] if line.startswith(f"  {bits} bits {width_verdict.upper()}"))
        assert "pts [" in decided or "cross-implementation" in decided or "no paired check" in decided
    own = [line.removeprefix("  > ") for line in printed if line.startswith("  > vprsnn-export ")]
    assert [line.split()[1] for line in own] == ["train", "verify", "localize"]
    # every hint runs as written
    hints = [line.removeprefix("  $ ") for line in printed if line.startswith("  $ vprsnn-export ")]
    assert len(hints) == 2
    for hint in hints:
        assert main([*shlex.split(hint)[1:], "--quiet"]) in (0, 1, 3), hint
    rerun = json.loads((out / "verify" / "report.json").read_text())
    assert rerun["verdict"] == verdict  # the verify hint reproduces the demo's verdict
    assert [r["verdict"] for r in rerun["runs"][0]["bits"]] == [widths[b] for b in DEMO_BITS]
    assert not any(" = 0.0" in line for line in printed if "limit" in line)  # points, never fractions
    assert (out / "float.npz").is_file()
    for bits in DEMO_BITS:
        folder = out / "deploy" / f"{bits}bit"
        model = load_fixed_point(folder / "model.npz")
        assert model.bits == bits and model.quantisation.per_neuron
        assert model.n_neurons == 2 * model.config.network.n_neurons  # the demo is an ensemble of two modules
        assert read_nir(folder / "model.nir").bits == bits
        assert read_loihi_model(folder / "loihi").bits == bits
        read_onnx(folder / "model.onnx")
    report = json.loads((out / "report" / "report.json").read_text())
    assert [r["bits"] for r in report["runs"][0]["bits"]] == list(DEMO_BITS)
    assert all(r["cross_implementation"]["passed"] for r in report["runs"][0]["bits"])
    assert report["settings"]["demo_profile"]["train.epochs"] == 2
    assert report["runs"][0]["config"]["train"]["epochs"] == 2  # the profile is in the checkpoint's config
    assert [len(r["modules"]) for r in report["runs"][0]["bits"]] == [2] * len(DEMO_BITS)
    assert "## Modules of the ensemble" in (out / "report" / "report.md").read_text()
    assert (out / "report" / "report.html").is_file() and (out / "report" / "report.md").is_file()
