"""End to end through the CLI on the embedded synthetic route."""

import json

import numpy as np
import pytest

from vprsnn_export.cli import main
from vprsnn_export.io.checkpoint import load_checkpoint

SMALL = ["--timesteps", "100", "--epochs", "8", "--neurons", "100"]


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("e2e") / "net.npz"
    code = main(
        [
            "train",
            "--data",
            "synthetic:40",
            "--reference",
            "summer",
            "--seed",
            "3",
            "--out",
            str(out),
            "--quiet",
            *SMALL,
        ]
    )
    assert code == 0
    return out


def test_checkpoint_holds_config_calibration_and_provenance(trained):
    ckpt = load_checkpoint(trained)
    assert ckpt.config.seed == 3 and ckpt.config.encoder.timesteps == 100 and ckpt.config.train.epochs == 8
    assert ckpt.calibration.shape == (100, 40) and ckpt.calibration.sum() > 0
    assert ckpt.reference_traversals == ["summer"]
    assert ckpt.data["source"] == "synthetic:40" and len(ckpt.data["manifest_sha256"]) == 64
    assert len(ckpt.history) == 8


def test_evaluate_json_beats_chance_by_a_wide_margin(trained, capsys):
    assert main(["evaluate", str(trained), "--query", "winter", "--k", "1,5", "--json", "--quiet"]) == 0
    payload = json.loads(capsys.readouterr().out)
    rows = {(r["strategy"], r["k"]): r for r in payload["results"]}
    assert set(rows) == {("standard", 1), ("weighted", 1), ("wprob", 1), ("wprob", 5)}
    chance = 1 / 40
    assert rows[("wprob", 1)]["accuracy"] > 5 * chance
    assert rows[("wprob", 5)]["accuracy"] > 10 * chance
    assert payload["config"]["seed"] == 3
    assert 0 <= payload["spike_stats"]["multi_candidate_step_fraction"] <= 1
    for row in payload["results"]:
        assert row["n_queries"] == 40
        assert 0 <= row["r_at_100p"] <= row["accuracy"] + 1e-12
    cost = payload["cost"]  # events per query: every input spike reaches all 100 neurons for all 100 steps
    assert cost["queries"] == 40 and cost["steps"] == 100 and cost["neuron_updates"] == 100 * 100
    assert cost["input_spikes"] > 0 and cost["synaptic_events"] == pytest.approx(100 * cost["input_spikes"])
    assert 0 < cost["template_macs"] <= 40 * cost["template_weights"] / 40
    assert cost["snn_weights"] == 100 * cost["template_weights"] / 40


def test_same_seed_gives_identical_checkpoint_weights(trained, tmp_path):
    again = tmp_path / "again.npz"
    assert (
        main(
            [
                "train",
                "--data",
                "synthetic:40",
                "--reference",
                "summer",
                "--seed",
                "3",
                "--out",
                str(again),
                "--quiet",
                *SMALL,
            ]
        )
        == 0
    )
    np.testing.assert_array_equal(load_checkpoint(again).weights, load_checkpoint(trained).weights)
    np.testing.assert_array_equal(load_checkpoint(again).calibration, load_checkpoint(trained).calibration)


def test_evaluate_table_output(trained, capsys):
    assert main(["evaluate", str(trained), "--query", "winter", "--quiet", "--baseline"]) == 0
    captured = capsys.readouterr()
    assert "wprob" in captured.out and "sad" in captured.out and "R@100P" in captured.out
    assert "events per query: SNN" in captured.err and "vs template" in captured.err


@pytest.mark.parametrize(
    "argv, message",
    [
        (["evaluate", "missing.npz", "--query", "winter"], "missing.npz: no such checkpoint"),
        (["train", "--data", "nowhere/places.csv", "--reference", "summer", "--out", "x.npz"], "nowhere"),
        (["train", "--data", "synthetic:10", "--reference", "autumn", "--out", "x.npz"], "autumn"),
        (["train", "--data", "synthetic:10", "--reference", "summer", "--places", "50:5", "--out", "x.npz"], "50"),
        (
            ["train", "--data", "synthetic:10", "--reference", "summer", "--set", "encoder.nope=1", "--out", "x.npz"],
            "encoder.nope",
        ),
        (["evaluate", "CKPT", "--query", "winter", "--k", "0"], "--k"),
    ],
)
def test_expected_errors_are_one_line_and_exit_2(argv, message, trained, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = [str(trained) if a == "CKPT" else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and message in err[0]
    assert not (tmp_path / "x.npz").exists()


def test_module_size_trains_an_ensemble_whose_modules_are_the_regions_trained_alone(tmp_path, capsys):
    """train --module-size P: M = ceil(places / P) modules side by side; module m is `train --places` of its region."""
    tiny = ["--timesteps", "30", "--epochs", "2", "--neurons", "8", "--seed", "5", "--quiet"]
    ensemble, alone = tmp_path / "ensemble.npz", tmp_path / "alone.npz"
    base = ["train", "--data", "synthetic:30", "--reference", "summer", *tiny]
    assert main([*base, "--module-size", "12", "--out", str(ensemble)]) == 0
    assert main([*base, "--places", "24:6", "--out", str(alone)]) == 0
    whole, last = load_checkpoint(ensemble), load_checkpoint(alone)
    assert whole.config.train.module_size == 12
    assert whole.weights.shape[1] == 3 * 8 and whole.calibration.shape == (24, 30)
    assert np.array_equal(whole.weights[:, 16:], last.weights)
    assert np.array_equal(whole.thresholds[16:], last.thresholds)
    assert len(whole.history[0]["module_active_neurons"]) == 3


def test_a_checkpoint_with_the_early_decision_on_stops_its_queries_early(trained, tmp_path, capsys):
    """config.early in the checkpoint: evaluate reads out the counts of the steps run and counts only those steps."""
    from dataclasses import replace

    from vprsnn_export.io.checkpoint import save_checkpoint

    ckpt = load_checkpoint(trained)
    early = tmp_path / "early.npz"
    save_checkpoint(early, replace(ckpt, config=ckpt.config.replace(**{"early.spikes": 5})))
    assert main(["evaluate", str(trained), "--query", "winter", "--json", "--quiet"]) == 0
    full = json.loads(capsys.readouterr().out)
    assert main(["evaluate", str(early), "--query", "winter", "--json", "--quiet"]) == 0
    stopped = json.loads(capsys.readouterr().out)
    assert stopped["config"]["early"] == {"margin": False, "spikes": 5} and "early" not in full["config"]
    assert 5 <= stopped["cost"]["steps"] < full["cost"]["steps"] == 100
    assert stopped["cost"]["synaptic_events"] < full["cost"]["synaptic_events"]


def test_the_early_decision_refuses_runs_without_state_isolation(trained, tmp_path, capsys):
    from dataclasses import replace

    from vprsnn_export.io.checkpoint import save_checkpoint

    ckpt = load_checkpoint(trained)
    early = tmp_path / "early.npz"
    save_checkpoint(early, replace(ckpt, config=ckpt.config.replace(**{"early.margin": True})))
    assert main(["evaluate", str(early), "--query", "winter", "--no-state-isolation", "--quiet"]) == 2
    assert "state isolation" in capsys.readouterr().err


def test_train_warns_when_a_module_has_fewer_neurons_than_places(tmp_path, capsys):
    """Issue 31: 724 places on one 400-neuron module trained without a word; now a warning with a --module-size."""
    base = ["train", "--data", "synthetic:12", "--reference", "summer", "--timesteps", "8", "--epochs", "0", "--quiet"]
    assert main([*base, "--neurons", "8", "--out", str(tmp_path / "a.npz")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "warning: 12 places per module but 8 neurons: the module cannot give every place a neuron of its own; "
        "train an ensemble with --module-size 2 (or more --neurons)"
    ]
    assert main([*base, "--neurons", "8", "--module-size", "6", "--out", str(tmp_path / "b.npz")]) == 0
    assert main([*base, "--neurons", "12", "--out", str(tmp_path / "c.npz")]) == 0
    assert capsys.readouterr().err == ""
