"""Every experiment's --quick size runs on the synthetic route and writes well-formed JSON, Markdown and plots."""

import json
import re
from pathlib import Path

import pytest

from experiments.command import experiment_modules
from experiments.common import regenerating_command
from experiments.settings import DOCS_RESULTS, NORDLAND, SUBSET, data_settings
from vprsnn_export.cli import build_parser, main
from vprsnn_export.errors import DataError

NAMES = sorted(experiment_modules())


@pytest.fixture(scope="module")
def out_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("results")


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("VPRSNN_CACHE", str(tmp_path_factory.getbasetemp() / "ckpt-cache"))


def test_every_paper_experiment_is_listed():
    assert {
        "assignment",
        "ablation",
        "state_isolation",
        "aggregation",
        "envelope",
        "scalability",
        "quantisation",
        "timing",
        "epochs",
    } <= set(NAMES)


@pytest.mark.parametrize("name", NAMES)
def test_quick_experiment_writes_json_markdown_and_plots(name, out_dir):
    assert main(["experiment", name, "--quick", "--out", str(out_dir), "--quiet"]) == 0
    results = json.loads((out_dir / f"{name}_quick.json").read_text())
    assert results["experiment"] == name
    assert results["provenance"]["settings"]["quick"] is True
    assert results["command"].startswith("vprsnn-export experiment")
    markdown = (out_dir / f"{name}_quick.md").read_text()
    assert markdown.startswith(f"# Experiment: {name}")
    assert re.search(r"\| *-?\d+(\.\d+)?", markdown), "the Markdown must hold a table of numbers"
    for image in re.findall(r"\]\(([^)]+\.png)\)", markdown):
        assert (out_dir / image).stat().st_size > 1000
    assert "nan" not in markdown.lower()


@pytest.mark.parametrize("name", ["aggregation", "assignment", "route", "scalability", "sweep"])
def test_experiments_that_show_a_baseline_show_cosine(name, tmp_path):
    """Issue 20: every experiment that prints SAD (or a learned result) prints cosine nearest neighbour too."""
    assert main(["experiment", name, "--quick", "--out", str(tmp_path), "--quiet"]) == 0
    assert "cosine" in (tmp_path / f"{name}_quick.md").read_text()
    assert '"cosine"' in (tmp_path / f"{name}_quick.json").read_text()


def test_unknown_experiment_is_a_clear_error(capsys):
    assert main(["experiment", "nope", "--quick"]) == 2
    assert "unknown experiment 'nope'" in capsys.readouterr().err


def test_the_data_path_comes_from_the_command_line_or_the_environment(monkeypatch, tmp_path):
    """--data DIR: its manifest and its subset (when present); a manifest file: itself; else $VPRSNN_DATA,
    else the repository's data folder relative to the working folder."""
    folder = tmp_path / "nordland"
    folder.mkdir()
    (folder / "places.csv").write_text("place\n")
    assert data_settings(str(folder)) == {"data": str(folder / "places.csv"), "subset": None}
    (folder / SUBSET).write_text("place\n")
    assert data_settings(str(folder)) == {"data": str(folder / "places.csv"), "subset": str(folder / SUBSET)}
    assert data_settings(str(folder / "places.csv")) == {"data": str(folder / "places.csv"), "subset": None}
    assert data_settings("synthetic:12") == {"data": "synthetic:12", "subset": None}
    monkeypatch.setenv("VPRSNN_DATA", str(folder))
    assert data_settings(None)["subset"] == str(folder / SUBSET)
    monkeypatch.delenv("VPRSNN_DATA")
    work = tmp_path / "repository"  # the default is ../shared/...: inside tmp_path from here
    work.mkdir()
    monkeypatch.chdir(work)  # not the repository root: the default folder is not there
    with pytest.raises(DataError, match="relative to the repository root"):
        data_settings(None)
    (work / NORDLAND).mkdir(parents=True)
    assert data_settings(None) == {"data": str(NORDLAND / "places.csv"), "subset": None}


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([], "no data folder or place manifest at ../shared/data/nordland_64x32_summer_winter: the default"),
        (["--data", "nowhere"], "no data folder or place manifest at nowhere: --data"),
        (["--data", " "], "--data: an empty path"),
    ],
)
def test_missing_data_is_one_line_before_any_work(monkeypatch, tmp_path, capsys, argv, message):
    monkeypatch.delenv("VPRSNN_DATA", raising=False)
    work = tmp_path / "a" / "repository"  # ../shared/... is inside tmp_path from here, and absent
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    assert main(["experiment", "assignment", "--out", str(tmp_path / "out"), *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "out").exists()


def test_default_output_is_outside_the_repository(monkeypatch, tmp_path):
    monkeypatch.delenv("VPRSNN_RESULTS", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))
    args = build_parser(["experiment", "assignment"]).parse_args(["experiment", "assignment"])
    assert Path(args.out) == tmp_path / ".cache" / "vprsnn-export" / "results"
    assert not args.update_docs
    monkeypatch.setenv("VPRSNN_RESULTS", str(tmp_path / "mine"))
    assert build_parser(["experiment"]).parse_args(["experiment", "sweep"]).out == str(tmp_path / "mine")


def test_update_docs_writes_the_repositorys_docs_results(monkeypatch, tmp_path):
    (tmp_path / "docs" / "results").mkdir(parents=True)
    monkeypatch.chdir(tmp_path)
    args = build_parser(["experiment"]).parse_args(["experiment", "assignment", "--update-docs"])
    assert args.update_docs and args.out == DOCS_RESULTS


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--update-docs"], "run it from the repository root"),
        (["--out", "x", "--update-docs"], "not allowed with argument"),
        (["--quick", "--update-docs"], "not with --quick"),
    ],
)
def test_update_docs_misuse_is_one_line(monkeypatch, tmp_path, capsys, argv, message):
    if "--quick" in argv:
        (tmp_path / "docs" / "results").mkdir(parents=True)
    monkeypatch.chdir(tmp_path)
    assert main(["experiment", "assignment", *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "docs" / "results" / "assignment.json").exists()


@pytest.mark.parametrize(
    ("results", "command"),
    [
        (
            {"command": "vprsnn-export experiment sweep --seeds 5"},
            "vprsnn-export experiment sweep --seeds 5 --update-docs",
        ),
        ({"command": "vprsnn-export experiment sweep --update-docs", "output": "docs/results"}, None),
        ({"command": "vprsnn-export experiment sweep", "output": "/home/u/.cache/vprsnn-export/results"}, None),
        ({"command": "vprsnn-export experiment sweep --out=/tmp/r"}, None),
    ],
)
def test_the_page_names_the_command_that_regenerates_it(results, command):
    assert regenerating_command(results) == (command or results["command"])


def _traversal_folders(root, n_reference: int, n_query: int, shift: int = 0):
    """summer/ and winter/ of the synthetic route (winter frame j shows place j + shift) in a folder data set."""
    import cv2

    from vprsnn_export.data.synthetic import synthetic_route

    route = synthetic_route(n_reference + shift, ("summer", "winter"))
    for name, images in (("summer", route["summer"][:n_reference]), ("winter", route["winter"][shift:][:n_query])):
        (root / name).mkdir(parents=True)
        for index, image in enumerate(images):
            cv2.imwrite(str(root / name / f"{index:03d}.png"), image)


def test_experiments_never_score_by_index_what_the_data_matches_otherwise(tmp_path, capsys):
    """Issue 31: a folder data set (one traversal per subfolder) is scored by index only where that is its own
    scoring; a ground truth matching queries to other places, or traversals of different lengths without one,
    are refused with one line naming the file or folder, before any training."""
    argv = ["experiment", "assignment", "--quick", "--seeds", "1", "--quiet", "--set", "train.epochs=1"]
    aligned = tmp_path / "aligned"
    _traversal_folders(aligned, 24, 24)
    assert data_settings(str(aligned)) == {"data": str(aligned), "subset": None}
    assert main([*argv, "--data", str(aligned), "--out", str(tmp_path / "a")]) == 0, capsys.readouterr().err
    shifted = tmp_path / "shifted"
    _traversal_folders(shifted, 24, 24, shift=3)
    pairs = "".join(f"{q},{(q + 3) % 24}\n" for q in range(24))  # winter j is summer place j + 3
    (shifted / "summer_winter_GT.csv").write_text("query,reference\n" + pairs, encoding="utf-8")
    unequal = tmp_path / "unequal"
    _traversal_folders(unequal, 30, 24)
    for folder, message in (
        (shifted, "summer_winter_GT.csv: its query frame 0 matches reference frame(s) [3], but experiments score"),
        (unequal, "the traversals hold different numbers of frames (summer 30, winter 24)"),
    ):
        capsys.readouterr()
        assert main([*argv, "--data", str(folder), "--out", str(tmp_path / "out")]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1 and message in err and str(folder) in err, err
    assert not (tmp_path / "out").exists()
