"""SequenceOptions: one set of defaults, one validation, no gamma (the config's is the one source)."""

import dataclasses
import inspect
import json

import numpy as np
import pytest

from vprsnn_export.config import Config
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.readout import aggregation
from vprsnn_export.readout.scoring import Readout
from vprsnn_export.readout.sequence import SequenceOptions


def test_gamma_comes_from_the_config_only():
    assert "gamma" not in {f.name for f in dataclasses.fields(SequenceOptions)}
    cfg = Config().replace(**{"assignment.gamma": 0.07})
    assert Readout.of(np.ones((4, 3)), cfg, SequenceOptions(ks=(1, 3))).gamma == 0.07
    with pytest.raises(InvalidValueError, match="config"):
        Readout.of(np.ones((4, 3)), {"assignment": {"gamma": 0.1}})  # type: ignore[arg-type]


def test_the_searches_share_the_options_defaults():
    options = SequenceOptions()
    for search in (aggregation.track_velocity, aggregation.smooth_velocity):
        defaults = inspect.signature(search).parameters
        assert defaults["span"].default == options.velocity_span
        assert defaults["memory"].default == options.velocity_memory
        assert defaults["rule"].default == options.rule
    assert inspect.signature(aggregation.aggregate).parameters["rule"].default == options.rule


@pytest.mark.parametrize(
    ("changes", "flag"),
    [
        ({"ks": (0,)}, "--k"),
        ({"ks": ()}, "--k"),
        ({"rule": "max"}, "aggregation rule"),
        ({"velocity": 0.0}, "--velocity"),
        ({"velocity": float("nan")}, "--velocity"),
        ({"velocity_candidates": ()}, "--velocity-search"),
        ({"velocity_estimate": "oracle"}, "velocity estimate"),
        ({"velocity_span": 0}, "--velocity-span"),
        ({"velocity_length": 0}, "--velocity-length"),
        ({"velocity_memory": -1}, "--velocity-memory"),
        ({"velocity_lag": -1}, "--velocity-lag"),
        ({"tolerance": -1}, "--match-window"),
        ({"velocity_span": True}, "--velocity-span"),
    ],
)
def test_bad_options_are_one_error_naming_the_option(changes, flag):
    with pytest.raises(InvalidValueError, match=flag):
        SequenceOptions(**changes)


def test_the_json_form_round_trips_and_reads_the_older_localize_form():
    options = SequenceOptions(ks=(3,), velocity_candidates=(0.5, 1.0), velocity_estimate="track", tolerance=2)
    assert SequenceOptions.from_dict(json.loads(json.dumps(dataclasses.asdict(options)))) == options
    older = {"k": 3, "rule": "product", "velocity": 1.0, "velocity_candidates": [0.5, 1.0], "velocity_span": 10}
    assert SequenceOptions.from_dict({**older, "velocity_memory": 50, "tolerance": 2}) == options
    with pytest.raises(InvalidValueError, match="unknown sequence options gamma"):
        SequenceOptions.from_dict({"gamma": 0.1})


def test_every_command_exposes_every_sequence_option():
    """Issue 33: evaluate, simulate, verify and localize offer one flag per SequenceOptions field (generated)."""
    from vprsnn_export.cli import build_parser
    from vprsnn_export.readout.sequence import option_flag

    parser = build_parser()
    commands = next(a for a in parser._actions if a.dest == "command").choices
    wanted = {option_flag(f.name) for f in dataclasses.fields(SequenceOptions)}
    for name in ("evaluate", "simulate", "verify", "localize"):
        flags = {flag for action in commands[name]._actions for flag in action.option_strings}
        assert wanted <= flags, (name, wanted - flags)
