"""Bad numbers and names on the command line: one line `error: <option>: ...`, exit 2, no traceback."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vprsnn_export.cli import main


@pytest.fixture(scope="module")
def checkpoint(tiny_checkpoint):
    """The session's tiny checkpoint file (tests/conftest.py)."""
    return str(tiny_checkpoint)


EVALUATE_CASES = [
    (["--k", "3", "--velocity", "nan"], "--velocity"),
    (["--velocity-search", "nan:nan:nan"], "--velocity-search"),
    (["--velocity-search", "0:inf:1"], "--velocity-search"),
    (["--velocity-search", "0:1:1e-6"], "--velocity-search"),
    (["--k", "100000000"], "--k"),
    (["--k", "50"], "--k"),
    (["--k", "0"], "--k"),
    (["--match-window=-3"], "--match-window"),
    (["--match-window", "99999999999999999999"], "--match-window"),
    (["--tolerance", "1"], "--tolerance: renamed to --match-window"),
    (["--threads", "0"], "--threads"),
]


@pytest.mark.parametrize(("extra", "message"), EVALUATE_CASES)
def test_evaluate_options(checkpoint, capsys, extra, message):
    assert main(["evaluate", checkpoint, "--query", "winter", "--quiet", *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1, err


@pytest.mark.parametrize("argv", [["evaluate"], ["evaluate", "x.npz", "--query", "w", "--nope"], ["nope"]])
def test_argparse_errors_are_one_line(capsys, argv):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and "usage" not in err


def test_negative_velocity_ranges_are_read_as_written(checkpoint, capsys):
    assert (
        main(["evaluate", checkpoint, "--query", "winter", "--quiet", "--k", "3", "--velocity-search", "-2:2:0.5"]) == 0
    )
    assert main(["evaluate", checkpoint, "--query", "winter", "--quiet", "--k", "3", "--velocity", "-1"]) == 0
    window = ["--velocity-search", "-1:1:0.5", "--velocity-estimate", "window"]
    assert main(["evaluate", checkpoint, "--query", "winter", "--quiet", "--k", "3", *window]) == 0


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["train", "--data", "synthetic:100000000000", "--reference", "summer", "--out", "x.npz"], "--data"),
        (
            ["train", "--data", "synthetic:10", "--places", "0:99999999999", "--reference", "summer", "--out", "x.npz"],
            "--places",
        ),
        (["experiment", "assignment", "--quick", "--seeds=-2"], "--seeds"),
        (["experiment", "assignment", "--quick", "--seeds", "0"], "--seeds"),
    ],
)
def test_out_of_range_numbers(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1


OPTION_VALUES = st.one_of(
    st.text(max_size=12),
    st.sampled_from(["nan", "inf", "-inf", "1e308", "-0", "0x10", "1_000", "3.5", "::", "1:2", "0:1:0", "-1:1:1e-9"]),
    st.integers(-(2**70), 2**70).map(str),
    st.floats().map(str),
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    option=st.sampled_from(
        ["--k", "--match-window", "--velocity", "--velocity-search", "--velocity-span", "--threads"]
    ),
    value=OPTION_VALUES,
)
def test_any_option_value_runs_or_is_one_line(checkpoint, capsys, option, value):
    capsys.readouterr()
    code = main(["evaluate", checkpoint, "--query", "winter", "--quiet", "--json", f"{option}={value}"])
    err = capsys.readouterr().err
    assert code in (0, 2), err
    if code == 2:
        assert err.startswith("error: ") and err.count("\n") == 1, err


def test_a_permission_denied_anywhere_is_one_line_and_exit_2(monkeypatch, capsys, tmp_path):
    """Issue 45: a folder or file the user may not read (root reads everything, so the refusal is simulated)."""
    import vprsnn_export.commands.evaluate as evaluate

    def denied(path):
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(evaluate, "load_checkpoint", denied)
    assert main(["evaluate", str(tmp_path / "net.npz"), "--query", "winter"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {tmp_path / 'net.npz'}: permission denied (Permission denied)"]
