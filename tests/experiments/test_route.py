"""experiment route on the tiny synthetic route: every readout, the SAD rows, the cost, --module-sizes."""

import pytest

from experiments import route
from experiments.common import Settings
from vprsnn_export.cli import main


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("VPRSNN_CACHE", str(tmp_path_factory.getbasetemp() / "route-cache"))


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    cache = tmp_path_factory.getbasetemp() / "route-cache"
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("VPRSNN_CACHE", str(cache))
        return route.run(Settings.quick_settings(progress=False, module_sizes=(8, 12)))


def test_every_network_is_read_out_every_way(results):
    assert [(n["module_size"], n["seed"]) for n in results["networks"]] == [(8, 1), (8, 2), (12, 1)]
    names = [r["readout"] for r in results["readouts"]]
    assert names == [name for name, *_ in route.READOUTS] and results["default_readout"] in names
    scopes = {r["readout"]: r["wta_scope"] for r in results["readouts"]}
    assert scopes[route.DEFAULT_READOUT] == "ensemble" and scopes[route.PREVIOUS_READOUT] == "module"
    for network in results["networks"]:
        assert network["modules"] == -(-24 // network["module_size"])
        assert {r["readout"] for r in network["rows"]} == set(names)
        estimated = [r for r in network["rows"] if r["strategy"] == "wprob-est"]
        assert {(r["readout"], r["k"]) for r in estimated} == {(route.DEFAULT_READOUT, 5), (route.DEFAULT_READOUT, 10)}
        none = next(r for r in network["readouts"] if r["readout"] == "none")
        assert none["silenced"] == 0 and len(none["modules"]) == network["modules"]
        # the two WTA scopes read the same trained weights differently: their rows differ
        default = [r for r in network["rows"] if r["readout"] == route.DEFAULT_READOUT and r["strategy"] == "wprob"]
        before = [r for r in network["rows"] if r["readout"] == route.PREVIOUS_READOUT and r["strategy"] == "wprob"]
        assert len(default) == len(before) == len(route.KS) and default != [
            dict(r, readout=route.DEFAULT_READOUT) for r in before
        ]


def test_the_provenance_names_the_preset_the_route_runs(results):
    assert results["provenance"]["settings"]["preset"] == route.ROUTE_PRESET == "dog"


def test_sad_rows_and_cost(results):
    assert set(results["baselines"]) == {"intensity", "dog_on_off", "cosine", "sad_nn"}
    for name in results["baselines"]:
        assert [r["k"] for r in results["baselines"][name]] == list(route.KS)
    assert {r["strategy"] for r in results["baselines"]["cosine"]} == {"cosine"}
    assert [c["module_size"] for c in results["cost"]] == [8, 12]
    assert all(c["train_seconds"]["mean"] >= 0 for c in results["cost"])


def test_rerun_from_the_cache_gives_the_same_rows(results):
    again = route.run(Settings.quick_settings(progress=False, module_sizes=(8, 12)))
    assert [n["rows"] for n in again["networks"]] == [n["rows"] for n in results["networks"]]
    assert all(n["cached"] for n in again["networks"])


def test_render_names_the_goals(results, tmp_path):
    page = route.render(dict(results, command="vprsnn-export experiment route --quick"), tmp_path, "r")
    assert "## Against storing the reference images (issue 20)" in page and (tmp_path / "r.png").stat().st_size > 1000
    assert "cosine NN, DoG" in page and "one WTA per module" in page


def test_module_sizes_option_is_checked(capsys):
    assert main(["experiment", "epochs", "--quick", "--module-sizes", "10"]) == 2
    assert "--module-sizes applies only to experiment route" in capsys.readouterr().err
    assert main(["experiment", "route", "--quick", "--module-sizes", "8,8"]) == 2
    assert "names a size twice" in capsys.readouterr().err
