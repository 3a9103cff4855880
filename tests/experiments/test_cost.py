"""experiment cost on a given checkpoint: every point read out, events = input spikes x neurons, early <= T."""

import json

import pytest

from vprsnn_export.cli import main


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cost")
    ckpt = folder / "net.npz"
    train = ["train", "--data", "synthetic:16", "--reference", "summer", "--seed", "2", "--out", str(ckpt)]
    assert main([*train, "--timesteps", "30", "--epochs", "2", "--neurons", "32", "--quiet"]) == 0
    assert main(["experiment", "cost", "--quick", "--checkpoint", str(ckpt), "--out", str(folder), "--quiet"]) == 0
    return json.loads((folder / "cost_quick.json").read_text())


def test_every_point_is_measured_on_the_given_network(results):
    (network,) = results["networks"]
    assert network["network"] == "net" and network["places"] == 16 and network["neurons"] == 32
    points = {p["point"]: p for p in network["points"]}
    assert {"T=30", "margin", "T=20", "T=15", "cosine"} <= set(points)
    for name, point in points.items():
        if name == "cosine":
            assert point["template_macs"] > 0
            continue
        cost = point["cost"]
        assert cost["synaptic_events"] == pytest.approx(32 * cost["input_spikes"])
        assert 0 < cost["steps"] <= point["timesteps"]
        assert {(r["strategy"], r["k"]) for r in point["rows"]} >= {("wprob", 1), ("wprob", 5), ("wprob", 10)}
    assert points["margin"]["cost"]["steps"] <= points["T=30"]["cost"]["steps"]
    assert points["T=15"]["rate_scale"] == pytest.approx(2 * points["T=30"]["rate_scale"])


def test_checkpoint_is_refused_by_other_experiments(capsys):
    assert main(["experiment", "epochs", "--quick", "--checkpoint", "x.npz"]) == 2
    assert "only to experiment cost" in capsys.readouterr().err


def test_networks_of_two_kinds_are_two_curves_beside_one_template(tmp_path):
    """A network that learnt at a longer window than it runs is another kind: its points carry the kind's name."""
    paths = []
    for name, extra in (
        ("a", []),
        ("b", ["--set", "train.timesteps=30", "--set", "train.rate_scale=0.25", "--set", "encoder.rate_scale=0.5"]),
    ):
        paths.append(tmp_path / f"{name}.npz")
        train = ["train", "--data", "synthetic:12", "--reference", "summer", "--seed", "2", "--out", str(paths[-1])]
        assert main([*train, "--timesteps", "15", "--epochs", "1", "--neurons", "16", "--quiet", *extra]) == 0
    run = ["experiment", "cost", "--quick", "--out", str(tmp_path), "--quiet"]
    assert main([*run, "--checkpoint", str(paths[0]), "--checkpoint", str(paths[1])]) == 0
    out = json.loads((tmp_path / "cost_quick.json").read_text())
    kinds = [n["kind"] for n in out["networks"]]
    assert kinds == ["1 x 16, T=15 r 0.25", "1 x 16, T=15 r 0.5 (learnt at T=30 r 0.25)"]
    names = [p["point"] for p in out["summary"]]
    assert names.count("cosine") == 1
    assert f"{kinds[0]}: T=15" in names and f"{kinds[1]}: T=15" in names
    assert (tmp_path / "cost_quick.png").stat().st_size > 0
