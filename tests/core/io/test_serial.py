"""vprsnn_export.io.serial: the generic dataclass <-> JSON mapping, by field options and type hints (read by dacite)."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import pytest

from vprsnn_export.errors import InvalidValueError
from vprsnn_export.io.serial import JsonDataclass, json_options, to_json


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
        *("name", "inner", "a", "b", "items", "pairs", "by_k", "nested", "mode"),
        *("anything", "other", "old", "double"),
    ]
    assert data["by_k"] == {"1": 0.25, "10": 0.75} and data["double"] == 2
    assert Outer.from_dict(json.loads(json.dumps(data))) == value


def test_missing_keys_take_their_defaults_or_fail():
    data = _value().to_dict()
    del data["old"], data["items"]
    loaded = Outer.from_dict(data)
    assert loaded.old == "n!" and loaded.items == () and loaded.computed_only == 7
    del data["name"]
    with pytest.raises(InvalidValueError, match=r"\(name: missing\)"):
        Outer.from_dict(data)


@pytest.mark.parametrize(
    ("key", "value", "named"),
    [
        ("name", 1, "name: expected str, got 1"),
        ("inner", [1], "inner: expected Inner, got [1]"),
        ("a", "one", "flat.a: expected int, got 'one'"),
        ("items", 3, "items: expected tuple[Inner, ...], got 3"),
        ("items", [{"b": 1.0}], "items.a: missing"),
        ("pairs", [1], "pairs: expected tuple[int, str]"),
        ("by_k", [1.0], "by_k: expected Mapping[int, float]"),
        ("by_k", {"one": 1.0}, "by_k: expected Mapping[int, float], got {'one': 1.0}"),
        ("by_k", "x", "by_k: expected Mapping[int, float], got 'x'"),
        ("nested", "ab", "nested: expected tuple[tuple[str, ...] | None, ...], got 'ab'"),
        ("nested", [["a"], "b"], "nested: expected tuple[str, ...], got 'b'"),
        ("mode", "z", "mode: expected Literal['x', 'y'], got 'z'"),
        ("name", "a\nb" * 100, None),
        ("maybe", "x\ny", "maybe: expected int | None, got 'x\\ny'"),
    ],
)
def test_bad_values_are_one_error_naming_the_field(key, value, named):
    data = _value().to_dict() | {key: value}
    if named is None:  # a legal value
        assert Outer.from_dict(data).name == value
        return
    with pytest.raises(InvalidValueError) as caught:
        Outer.from_dict(data)
    message = str(caught.value)
    assert message.startswith("malformed Outer (" + named) and "\n" not in message, message


def test_a_missing_key_is_one_error_naming_it():
    with pytest.raises(InvalidValueError, match=r"malformed Inner \(a: missing\)"):
        Inner.from_dict({"b": 0.5})
    with pytest.raises(InvalidValueError, match="expected Inner, got 'x'"):
        Inner.from_dict("x")


def test_numpy_scalars_and_arrays_become_json():
    assert to_json({np.int64(3): np.float32(0.5), "a": np.arange(3), "b": (np.bool_(True),)}) == {
        "3": 0.5,
        "a": [0, 1, 2],
        "b": [True],
    }
    assert json.dumps(to_json(Inner(np.int64(2), np.float64(0.5)))) == '{"a": 2, "b": 0.5}'


def test_numbers_are_read_as_their_field_types():
    """An integer in a float field is a float (written back as 2.0), numpy scalars are Python numbers."""
    loaded = Inner.from_dict({"a": np.int64(2), "b": 2})
    assert type(loaded.a) is int and type(loaded.b) is float and json.dumps(loaded.to_dict()) == '{"a": 2, "b": 2.0}'
    with pytest.raises(InvalidValueError, match=r"a: expected int, got 2\.5"):
        Inner.from_dict({"a": 2.5})
