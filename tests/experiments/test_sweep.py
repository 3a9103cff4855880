"""experiment sweep: a grid of variants over seeds and selections, trained networks shared and cached."""

import json

import pytest

from experiments import common, sweep
from experiments.common import document
from vprsnn_export.cli import main


class CountingTrainer:
    """Wraps train_and_calibrate and counts the networks actually trained (cache misses)."""

    def __init__(self):
        self.calls = 0
        self.train = common.train_and_calibrate

    def __call__(self, *args, **kwargs):
        self.calls += 1
        return self.train(*args, **kwargs)


def run_sweep(out, *extra):
    trainer = CountingTrainer()
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(common, "train_and_calibrate", trainer)
        code = main(["experiment", "sweep", "--quick", "--seeds", "1", "--out", str(out), "--quiet", *extra])
    assert code == 0
    return json.loads((out / "sweep_quick.json").read_text()), trainer.calls


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sweep-cache")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("VPRSNN_CACHE", str(folder))
        yield folder


@pytest.fixture(scope="module")
def default_sweep(cache, tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep")
    results, trainings = run_sweep(out)
    return out, results, trainings


def test_every_variant_selection_and_k_is_measured(default_sweep):
    _, results, _ = default_sweep
    names = [v.name for v in sweep.DEFAULT_GRID]
    assert [v["name"] for v in results["grid"]] == names
    for selection in sweep.SELECTIONS:
        block = results[selection]
        assert [v["variant"] for v in block["variants"]] == names
        for entry in block["variants"]:
            measured = {(r["strategy"], r["k"]) for r in entry["summary"]}
            assert {
                ("wprob", 1),
                ("wprob", 5),
                ("standard", 1),
                ("sad", 1),
                ("sad", 5),
                ("cosine", 1),
                ("cosine", 5),
            } <= measured
            assert all(r["accuracy"]["n"] == 1 for r in entry["summary"])


def test_readout_only_variants_reuse_the_trained_network(default_sweep, cache, tmp_path):
    _, results, trainings = default_sweep
    # 3 training configs (paper, dog, dog-sigma1-2) x 1 seed x 2 selections; the gamma variants train nothing
    assert trainings == 6
    for selection in sweep.SELECTIONS:
        networks = {v["variant"]: v["network"] for v in results[selection]["variants"]}
        assert networks == {
            "paper": "paper",
            "paper+gamma0.1": "paper",
            "dog": "dog",
            "dog+gamma0.1": "dog",
            "dog-sigma1-2": "dog-sigma1-2",
        }
    # a second sweep over the same networks with another readout trains nothing: the cache serves them
    again, trainings = run_sweep(tmp_path, "--grid", "a=paper,assignment.gamma=0.3", "--grid", "b=dog")
    assert trainings == 0
    assert [v["variant"] for v in again["subset"]["variants"]] == ["a", "b"]
    counts = {
        name: [r for r in block["per_seed"][0] if r["strategy"] == "standard"]
        for name, block in (("paper", results["subset"]["variants"][0]), ("a", again["subset"]["variants"][0]))
    }
    assert counts["paper"] == counts["a"]  # Standard does not depend on gamma: the same network and counts


def test_render_survives_a_json_round_trip(default_sweep, tmp_path):
    out, results, _ = default_sweep
    reloaded = json.loads(json.dumps(results))
    page = document(
        "sweep", sweep.DESCRIPTION, "sweep_quick", reloaded, sweep.render(reloaded, tmp_path, "sweep_quick")
    )
    assert page == (out / "sweep_quick.md").read_text()
    assert (tmp_path / "sweep_quick.png").stat().st_size > 1000
    assert "| paper+gamma0.1 | paper |" in page
    assert "| SAD k=1 acc / R@100P % | SAD k=5 acc / R@100P % | cosine k=1 acc / R@100P % | cosine k=5" in page


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["sweep", "--grid", "x"], "--grid expects NAME=PRESET[,KEY=VALUE...]"),
        (["sweep", "--grid", "x=assignment.gamma=0.1"], "--grid expects NAME=PRESET[,KEY=VALUE...]"),
        (["sweep", "--grid", "x=nope"], "--grid x: unknown preset 'nope'"),
        (["sweep", "--grid", "x=dog,assignment.nokey=1"], "--grid x: unknown config key 'assignment.nokey'"),
        (["sweep", "--grid", "x=dog", "--grid", "x=paper"], "variant name 'x' given more than once"),
        (["assignment", "--grid", "x=dog"], "--grid applies only to experiment sweep"),
    ],
)
def test_a_bad_grid_entry_is_a_one_line_error(args, message, capsys, tmp_path):
    assert main(["experiment", *args, "--quick", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())
