"""ReadoutOptions take gamma from the config (its one source)."""

import dataclasses

import pytest

from vprsnn_export.config import Config
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.runtime.evaluation import ReadoutOptions


def test_gamma_comes_from_the_config():
    cfg = Config().replace(**{"assignment.gamma": 0.07})
    options = ReadoutOptions.from_config(cfg, ks=(1, 3), rule="sum")
    assert (options.gamma, options.ks, options.rule) == (0.07, (1, 3), "sum")
    other = Config().replace(**{"assignment.gamma": 0.3})
    moved = options.with_config(other)
    assert moved.gamma == 0.3 and dataclasses.replace(moved, gamma=0.07) == options


def test_a_config_is_required():
    with pytest.raises(InvalidValueError, match="config"):
        ReadoutOptions.from_config({"assignment": {"gamma": 0.1}})  # type: ignore[arg-type]
