"""Every figure the README and docs/results/summary.md quote from docs/results equals the JSON its page is
rendered from.

Each case formats the figures from the committed JSON the way the text writes them (percent with one decimal,
mean ± std over seeds, as the pages do) into the text's own words, and asserts that sentence is in the README
(``README_CASES``) or in the long form of the results (``CASES``, docs/results/summary.md): a regenerated JSON
whose numbers moved fails here until the text is updated with it.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from experiments.common import pct

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"


def readme() -> str:
    return " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())


def summary_page() -> str:
    return " ".join((RESULTS / "summary.md").read_text(encoding="utf-8").split())


def results(stem: str) -> dict:
    return json.loads((RESULTS / f"{stem}.json").read_text(encoding="utf-8"))


def row(summary: list[dict], strategy: str, k: int, **where: object) -> dict:
    """The one summary row of ``strategy`` at ``k`` (and ``where``'s other keys)."""
    (found,) = [
        r for r in summary if r["strategy"] == strategy and r["k"] == k and all(r[f] == v for f, v in where.items())
    ]
    return found


def mean(value: dict | float, digits: int = 1) -> str:
    """A percentage as the README writes a single figure: 100 x mean (or the value), ``digits`` decimals."""
    number = value["mean"] if isinstance(value, dict) else value
    return f"{100 * number:.{digits}f}"


def assignment() -> str:
    data = results("assignment")
    subset, consecutive = data["subset"]["summary"], data["consecutive"]["summary"]
    wprob, standard = row(subset, "wprob", 1), row(subset, "standard", 1)
    k5 = row(consecutive, "wprob", 5)
    return (
        f"subset W+Prob reaches {pct(wprob['accuracy'])} % accuracy, R@100P {pct(wprob['r_at_100p'])} % "
        f"(Standard {pct(standard['accuracy'])} %); on 100 consecutive places W+Prob k=5 reaches "
        f"{pct(k5['accuracy'])} %, R@100P {pct(k5['r_at_100p'])} %. The no-learning SAD baseline on the same "
        f"images gets {mean(row(subset, 'sad', 1)['accuracy'], 0)} % (subset) and "
        f"{mean(row(consecutive, 'sad', 5)['accuracy'], 0)} % at k=5, cosine nearest neighbour "
        f"{mean(row(subset, 'cosine', 1)['accuracy'], 0)} % and {mean(row(consecutive, 'cosine', 5)['accuracy'], 0)} %"
    )


def route() -> str:
    data = results("route")
    size = data["main_module_size"]
    ks = data["ks"]

    def snn(readout: str, metric: str, with_std: bool) -> str:
        cells = [row(data["summary"], "wprob", k, readout=readout, module_size=size)[metric] for k in ks]
        return " / ".join(pct(c) if with_std else mean(c) for c in cells)

    def baseline(name: str, metric: str) -> str:
        return " / ".join(
            mean(row(data["baselines"][name], r["strategy"], r["k"])[metric]) for r in data["baselines"][name]
        )

    default, previous = data["default_readout"], data["previous_readout"]
    seconds = sorted(n["train_seconds"] for n in data["networks"] if n["module_size"] == size)
    return (
        f"W+Prob {snn(default, 'accuracy', True)} % at k = {' / '.join(map(str, ks))} "
        f"(R@100P {snn(default, 'r_at_100p', False)} %); one WTA per module (the earlier default) gave "
        f"{snn(previous, 'accuracy', False)} %. **The strongest no-learning baseline on the same images is still "
        f"better: cosine nearest neighbour on the DoG input gets {baseline('cosine', 'accuracy')} % "
        f"(R@100P {baseline('cosine', 'r_at_100p')} %)**; SAD on the DoG input {baseline('sad_nn', 'accuracy')} %."
        f" | Training the 24 modules took {seconds[0]:.0f}-{seconds[-1]:.0f} s"
    )


def timing() -> str:
    data = results("timing")

    def path(name: str, batch: int) -> dict:
        (found,) = [r for r in data["throughput"] if r["T"] == 300 and r["batch"] == batch and r["path"] == name]
        return found

    return (
        f"At T = 300, 100 queries batched: integer {path('integer', 100)['queries_per_s']:.0f} queries/s, float "
        f"{path('float', 100)['queries_per_s']:.0f}, dense-BLAS bound {path('dense_bound', 100)['queries_per_s']:.0f}, "
        f"torch loop {path('float_torch_loop', 100)['queries_per_s']:.0f}; one query alone: "
        f"{path('integer', 1)['ms_per_query']:.2f} ms integer, {path('float', 1)['ms_per_query']:.2f} ms float. "
        f"Training the default configuration on {data['training_images']} places ({data['training_epochs']} epochs): "
        f"{data['training_seconds']:.1f} s."
    )


def sweep() -> str:
    data = results("sweep")

    def summary(selection: str, variant: str) -> list[dict]:
        (found,) = [v for v in data[selection]["variants"] if v["variant"] == variant]
        return found["summary"]

    paper_subset, paper_run = summary("subset", "paper"), summary("consecutive", "paper")
    dog_subset, dog_run = summary("subset", "dog"), summary("consecutive", "dog")
    return (
        f"(W+Prob k=1: {pct(row(paper_subset, 'wprob', 1)['accuracy'])} % on the subset, SAD "
        f"{mean(row(paper_subset, 'sad', 1)['accuracy'], 0)} %; {pct(row(paper_run, 'wprob', 1)['accuracy'])} % on "
        f"places 1000-1099, SAD {mean(row(paper_run, 'sad', 1)['accuracy'], 0)} %). The default centre-surround "
        f"ON/OFF input channels lift W+Prob k=1 to {pct(row(dog_subset, 'wprob', 1)['accuracy'])} % on the subset "
        f"and {pct(row(dog_run, 'wprob', 1)['accuracy'])} % on places 1000-1099 (k=5: "
        f"{mean(row(dog_subset, 'wprob', 5)['accuracy'])} % and {mean(row(dog_run, 'wprob', 5)['accuracy'])} %, "
        f"R@100P {mean(row(dog_subset, 'wprob', 5)['r_at_100p'])} % and "
        f"{mean(row(dog_run, 'wprob', 5)['r_at_100p'])} %), above SAD on the same images but below cosine nearest "
        f"neighbour on them ({mean(row(dog_subset, 'cosine', 1)['accuracy'], 0)} % on the subset and "
        f"{mean(row(dog_run, 'cosine', 1)['accuracy'], 0)} % on places 1000-1099 at k=1"
    )


def adaptation() -> str:
    data = results("adaptation")

    def whole(matcher: str) -> str:
        return " / ".join(
            mean(
                next(r for r in data["summary"] if r["fold"] == "all" and r["matcher"] == matcher and r["k"] == k)[
                    "accuracy"
                ]
            )
            for k in data["ks"]
        )

    return (
        f"it lifts the SNN from {whole('SNN')} % to {whole('SNN, adapted')} % at k = 1 / 5 / 10, but cosine on the "
        f"same adapted input gets {whole('cosine, adapted')} %, above it at every k"
    )


def route_table() -> str:
    """The README's dev-route rows: the default ensemble (route.json), lean and cosine (cost.json)."""
    data = results("route")
    size, ks = data["main_module_size"], data["ks"]
    default = [row(data["summary"], "wprob", k, readout=data["default_readout"], module_size=size) for k in ks]
    cells = [pct(r["accuracy"]) for r in default] + [pct(default[ks.index(5)]["r_at_100p"])]
    cost = {point["point"]: point for point in results("cost")["summary"]}
    lean = next(p for name, p in cost.items() if name.startswith("24 x 100") and name.endswith(": T=80"))
    cosine = cost["cosine"]

    def cost_cells(point: dict, with_std: bool) -> list[str]:
        rows = {r["k"]: r for r in point["rows"]}
        values = [rows[k]["accuracy"] for k in ks] + [rows[5]["r_at_100p"]]
        return [pct(v) if with_std else mean(v) for v in values]

    return (
        "| SNN, default (24 modules x 400 neurons, 3 seeds) | " + " | ".join(cells) + " |"
        " | | SNN, `--preset lean` (24 x 100, 3 seeds) | " + " | ".join(cost_cells(lean, True)) + " | "
        f"{lean['cost']['synaptic_events'] / 1e6:.2f} M |"
        " | | cosine nearest neighbour on the same DoG input | " + " | ".join(cost_cells(cosine, False)) + " | "
        f"{cosine['cost']['synaptic_events'] / 1e6:.2f} M multiply-adds |"
        " | | SAD nearest neighbour on the same DoG input | "
        + " | ".join(
            mean(row(data["baselines"]["sad_nn"], "sad", k)[m])
            for k, m in (*((k, "accuracy") for k in ks), (5, "r_at_100p"))
        )
        + " | "
    )


def quantisation_dev_route() -> str:
    """The README's verdict table: W+Prob k=1 accuracy and R@100P at k=5 and k=10 of each width, with verdicts."""
    data = results("runs/quantisation_dev_route")

    def cell(check: dict) -> str:
        text = f"{100 * check['difference']:+.1f} [{100 * check['low']:+.1f}, {100 * check['high']:+.1f}] {check['verdict']}"
        return text + (f" (~{check['queries_to_decide']} queries)" if check["verdict"] == "undecided" else "")

    rows = []
    for width in data["bits"]:
        checks = {(c["strategy"], c["k"], c["metric"]): c for c in width["paired"]}
        cells = [checks["wprob", 1, "accuracy"], checks["wprob", 5, "r_at_100p"], checks["wprob", 10, "r_at_100p"]]
        rows.append(f"| {width['bits']} | {width['verdict']} | " + " | ".join(map(cell, cells)) + " |")
    return f"seed 1, {data['n_queries']} queries; | | " + " | | ".join(rows)


README_CASES: dict[str, Callable[[], str]] = {
    "adaptation": adaptation,
    "route": route_table,
    "runs/quantisation_dev_route": quantisation_dev_route,
}
CASES: dict[str, Callable[[], str]] = {
    "assignment": assignment,
    "route": route,
    "timing": timing,
    "sweep": sweep,
}


@pytest.mark.parametrize("stem", sorted(README_CASES))
def test_readme_quotes_its_json(stem):
    text = readme()
    for sentence in README_CASES[stem]().split(" | | "):
        assert sentence in text, f"README.md does not quote docs/results/{stem}.json as: {sentence!r}"


@pytest.mark.parametrize("stem", sorted(CASES))
def test_the_results_summary_quotes_its_json(stem):
    text = summary_page()
    for sentence in CASES[stem]().split(" | "):
        assert sentence in text, f"docs/results/summary.md does not quote docs/results/{stem}.json as: {sentence!r}"


def test_the_texts_cite_the_pages_they_quote():
    assert all(f"experiment {stem}" in readme() or f"results/{stem}.json" in readme() for stem in README_CASES)
    assert all(f"experiment {stem}" in summary_page() for stem in CASES)


def test_the_readme_is_read_in_five_minutes():
    assert len((ROOT / "README.md").read_text(encoding="utf-8").splitlines()) < 120
