"""The typed config refuses every invalid value with one message naming the key; legal extremes pass."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from vprsnn_export.cli import main
from vprsnn_export.config import RANGES, Config
from vprsnn_export.errors import InvalidValueError

BAD = [
    ("encoder.timesteps", "abc", "expected an integer"),
    ("encoder.timesteps", None, "expected an integer"),
    ("encoder.timesteps", [1], "expected an integer"),
    ("encoder.timesteps", 0, "outside"),
    ("encoder.timesteps", 2.5, "expected an integer"),
    ("preprocess.patch_size", 0, "outside"),
    ("stdp.tau_pre", 0, "outside"),
    ("stdp.w_max", 0, "outside"),
    ("network.n_neurons", 0, "outside"),
    ("network.n_neurons", -5, "outside"),
    ("network.theta_init", -1, "outside"),
    ("network.beta", 1.5, "outside"),
    ("assignment.gamma", math.nan, "finite"),
    ("encoder.rate_scale", -1, "outside"),
    ("encoder.rate_scale", math.inf, "finite"),
    ("homeostasis.theta_min", 200.0, "exceeds theta_max"),
    ("network.wta", "yes", "true/false"),
    ("seed", "1", "expected an integer"),
]


@pytest.mark.parametrize(("key", "value", "message"), BAD)
def test_invalid_values_name_the_key(key, value, message):
    with pytest.raises(InvalidValueError, match=message) as caught:
        Config().replace(**{key: value})
    assert key.split(".")[-1] in str(caught.value)


@pytest.mark.parametrize(
    "changes",
    [
        {"encoder.timesteps": 1},
        {"network.n_neurons": 1},
        {"train.epochs": 0},
        {"network.beta": 1.0},
        {"assignment.gamma": 0.0},
        {"homeostasis.eta": 0.0},
    ],
)
def test_legal_extremes_are_accepted(changes):
    assert Config().replace(**changes).to_dict() != {}


@given(key=st.sampled_from(sorted(RANGES)), value=st.one_of(st.floats(allow_nan=True), st.integers(-(2**70), 2**70)))
def test_any_number_is_accepted_or_refused_with_the_key(key, value):
    try:
        Config().replace(**{key: value})
    except InvalidValueError as exc:
        assert key.split(".")[-1] in str(exc)


def test_the_command_line_reports_one_line_and_exit_2(capsys, tmp_path):
    code = main(["train", "--data", "synthetic:10", "--reference", "summer", "--out", str(tmp_path / "t.npz"),
                 "--set", "encoder.timesteps=abc", "--quiet"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and err.startswith("error: config.encoder.timesteps")
    assert not (tmp_path / "t.npz").exists()


@pytest.mark.parametrize("key", ["preprocess.channels", "network.wta_scope"])
@pytest.mark.parametrize("value", [[1], {"a": 1}, 3, None])
def test_a_name_setting_that_is_not_text_is_refused(key, value):
    with pytest.raises(InvalidValueError, match=key.split(".")[1]):
        Config().replace(**{key: value})


def test_the_early_section_is_written_only_when_it_is_used():
    """Files that do not use the early decision stay byte-identical: the section at its defaults is left out."""
    from vprsnn_export.config import Config

    plain = Config()
    assert "early" not in plain.to_dict() and Config.from_dict(plain.to_dict()) == plain
    early = plain.replace(**{"early.margin": True, "early.spikes": 40})
    assert early.to_dict()["early"] == {"margin": True, "spikes": 40}
    assert Config.from_dict(early.to_dict()) == early


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ([1], "config: expected a mapping, got list"),
        ({"colour": 1}, "config: unknown keys ['colour']"),
        ({"encoder": {"timestep": 1}}, "config.encoder: unknown keys ['timestep']"),
        ({"encoder": 5}, "config.encoder: expected a mapping, got int"),
        ({"encoder": {"timesteps": True}}, "config.encoder.timesteps: expected an integer, got True"),
        ({"encoder": {"timesteps": 2.5}}, "config.encoder.timesteps: expected an integer, got 2.5"),
        ({"encoder": {"rate_scale": "fast"}}, "config.encoder.rate_scale: expected a number, got 'fast'"),
        ({"network": {"wta": 1}}, "config.network.wta: expected true/false, got 1"),
    ],
)
def test_a_file_s_config_is_refused_naming_the_key_and_the_problem(data, message):
    with pytest.raises(InvalidValueError) as caught:
        Config.from_dict(data)
    assert str(caught.value) == message


def test_a_file_s_config_reads_integral_floats_and_numeric_text():
    cfg = Config.from_dict({"encoder": {"timesteps": 150.0, "rate_scale": "0.5"}, "seed": 7})
    assert (cfg.encoder.timesteps, cfg.encoder.rate_scale, cfg.seed) == (150, 0.5, 7)
    assert type(cfg.encoder.timesteps) is int and cfg.network == Config().network
