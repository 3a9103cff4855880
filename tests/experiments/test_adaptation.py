"""experiment adaptation on the tiny synthetic route: cross-fitted folds, every matcher, a page per data set."""

import pytest

from experiments import adaptation
from experiments.common import Settings
from experiments.settings import data_settings


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("VPRSNN_CACHE", str(tmp_path_factory.getbasetemp() / "adaptation-cache"))
        return adaptation.run(Settings.quick_settings(progress=False))


def test_each_fold_learns_only_from_the_other_folds(results):
    assert results["folds"] == 2 and results["n_places"] == 24
    assert [(r["seed"], r["fold"]) for r in results["results"]] == [(1, 0), (1, 1), (2, 0), (2, 1)]
    for r in results["results"]:
        scored = r["places"]
        learnt = r["learnt_from"]
        assert scored == ("0:12" if r["fold"] == 0 else "12:12")
        assert f"(places {'12:12' if r['fold'] == 0 else '0:12'};" in learnt  # never the fold it scores
        assert [row["matcher"] for row in r["rows"]] == list(adaptation.MATCHERS)
        for row in r["rows"]:
            assert set(row["scores"]) == {"1", "5", "10"}
            assert all(0 <= v["r_at_100p"] <= v["accuracy"] <= 1 for v in row["scores"].values())


def test_the_adapted_and_plain_networks_differ(results):
    by = {(r["seed"], r["fold"]): r for r in results["results"]}
    plain = {key: r["rows"][1]["scores"] for key, r in by.items()}
    assert plain[(1, 0)] != plain[(2, 0)]  # the plain network is trained once per seed
    for key, r in by.items():
        cosine, adapted_cosine = r["rows"][3]["scores"], r["rows"][2]["scores"]
        assert cosine == by[(1, key[1])]["rows"][3]["scores"]  # plain cosine does not depend on the seed
        assert adapted_cosine != cosine or r["rows"][0]["scores"] != r["rows"][1]["scores"]


def test_the_page_names_its_data_set(results, tmp_path):
    body = adaptation.render(results, tmp_path)
    assert "| 0 (0:12) | SNN, adapted |" in body and "at or above cosine on the plain input" in body
    assert adaptation.stem(Settings()) == "adaptation"
    lens = Settings(**data_settings("../shared/data/lens_example_davis128"))
    assert adaptation.stem(lens) == "adaptation_lens_example_davis128"


def test_the_whole_route_pools_the_folds_decisions(results):
    """At k=1 a query's decision does not depend on its fold's other queries: the pooled accuracy is the mean of
    the two equal folds'."""
    for whole in results["whole_route"]:
        folds = [r for r in results["results"] if r["seed"] == whole["seed"]]
        for i, row in enumerate(whole["rows"]):
            per_fold = [f["rows"][i]["scores"]["1"]["accuracy"] for f in folds]
            assert row["scores"]["1"]["accuracy"] == pytest.approx(sum(per_fold) / 2)
    assert {s["fold"] for s in results["summary"]} == {0, 1, "all"}
