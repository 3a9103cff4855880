"""vprsnn_export.io.serial: the generic dataclass <-> JSON mapping, by field options and type hints."""

from __future__ import annotations

import enum
import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import pytest

from vprsnn_export.io.serial import JsonDataclass, from_json, json_options, to_json


class Colour(enum.Enum):
    RED = "red"
    BLUE = "blue"


@dataclass(frozen=True)
class Inner(JsonDataclass):
    a: int
    b: float | None = None


@dataclass(frozen=True)
class Outer(JsonDataclass):
    name: str
    inner: Inner
    flat: Inner = field(metadata=json_options(flatten=True))
    items: tuple[Inner, ...] = ()
    pairs: tuple[int, str] = (0, "")
    by_k: Mapping[int, float] = field(default_factory=dict)
    nested: tuple[tuple[str, ...] | None, ...] = ()
    colour: Colour = Colour.RED
    mode: Literal["x", "y"] = "x"
    anything: Any = None
    renamed: int = field(default=0, metadata=json_options(key="other"))
    maybe: int | None = field(default=None, metadata=json_options(omit="none"))
    old: str = field(default="", metadata=json_options(missing_from=lambda data: data["name"] + "!"))
    computed_only: int = field(default=7, metadata=json_options(write=False, missing=7))

    __json_extra__ = ("double",)

    @property
    def double(self) -> int:
        return 2 * self.inner.a


def _value() -> Outer:
    return Outer(
        "n",
        Inner(1, 0.5),
        Inner(2),
        (Inner(3, 1.5),),
        (4, "four"),
        {1: 0.25, 10: 0.75},
        (("a", "b"), None),
        Colour.BLUE,
        "y",
        {"free": [1, 2]},
        5,
        None,
        "kept",
    )


def test_round_trip_and_keys():
    value = _value()
    data = value.to_dict()
    assert list(data) == [
        *("name", "inner", "a", "b", "items", "pairs", "by_k", "nested", "colour", "mode"),
        *("anything", "other", "old", "double"),
    ]
    assert data["by_k"] == {"1": 0.25, "10": 0.75} and data["colour"] == "blue" and data["double"] == 2
    assert Outer.from_dict(json.loads(json.dumps(data))) == value


def test_missing_keys_take_their_defaults_or_fail():
    data = _value().to_dict()
    del data["old"], data["items"]
    loaded = Outer.from_dict(data)
    assert loaded.old == "n!" and loaded.items == () and loaded.computed_only == 7
    del data["name"]
    with pytest.raises(KeyError):
        Outer.from_dict(data)


@pytest.mark.parametrize(
    ("tp", "data"),
    [
        (int, [1]),
        (float, None),
        (tuple[int, ...], 3),
        (tuple[int, str], [1]),
        (Mapping[int, float], [1.0]),
        (Literal["x"], "z"),
        (Colour, "green"),
        (Inner, [1]),
        (int, "one"),
    ],
)
def test_bad_values_raise(tp, data):
    with pytest.raises((TypeError, ValueError, KeyError)):
        from_json(tp, data)


def test_numpy_scalars_and_arrays_become_json():
    assert to_json({np.int64(3): np.float32(0.5), "a": np.arange(3), "b": (np.bool_(True),)}) == {
        "3": 0.5,
        "a": [0, 1, 2],
        "b": [True],
    }
    assert json.dumps(to_json(Inner(np.int64(2), np.float64(0.5)))) == '{"a": 2, "b": 0.5}'
