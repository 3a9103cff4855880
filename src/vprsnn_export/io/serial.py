"""One generic mapping between frozen dataclasses and JSON values, driven by their fields and type hints.

``to_json(value)`` turns a dataclass (nested dataclasses, tuples, lists, mappings, Optional,
enums, literals, numpy scalars and arrays) into plain JSON values; ``from_json(tp, data)``
is its inverse for the type ``tp``: every field is converted by its type hint
(``tuple[int, ...]`` from a list, ``Mapping[int, float]`` from an object with string keys,
``X | None`` from null or an X). ``from_json(type(x), to_json(x)) == x`` for every value
whose types are hinted.

A field's JSON form is the field name and its value, unless its metadata
(``field(metadata=json_options(...))``) says otherwise:

* ``key``: another JSON key (``float_values`` is ``"float"``);
* ``flatten``: the value's keys sit in the parent object (a dataclass: its fields; a mapping:
  the keys ``flatten`` lists);
* ``omit``: ``"none"`` leaves the key out when the value is None; a function ``omit(obj)`` when it says so;
* ``missing`` / ``missing_from``: the value when a file lacks the key (older files), a constant or a
  function of the parent object's data; by default the field's own default, else a KeyError;
* ``write=False``: never written (read from ``missing_from`` only).

Values typed ``Any`` are free-form JSON (settings, a config's dict) and are written as they are.
A class may list computed keys written after its fields (``__json_extra__``: property names,
ignored on reading) and a key order (``__json_order__``). A class that defines ``to_dict`` /
``from_dict`` itself (the checkpoint's config, the quantisation header) is handed to them.
"""

from __future__ import annotations

import copy
import dataclasses
import enum
import functools
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from typing import Any, TypeVar, Union

import numpy as np

T = TypeVar("T")

_NO_VALUE = object()


def json_options(
    *,
    key: str | None = None,
    flatten: bool | tuple[str, ...] = False,
    omit: str | Callable[[Any], bool] | None = None,
    missing: Any = _NO_VALUE,
    missing_from: Callable[[Mapping[str, Any]], Any] | None = None,
    write: bool = True,
) -> dict[str, Any]:
    """A field's JSON options (see the module docstring), as ``dataclasses.field(metadata=json_options(...))``."""
    options = {"key": key, "flatten": flatten, "omit": omit, "missing": missing, "missing_from": missing_from}
    return {"json": {**options, "write": write}}


@dataclasses.dataclass(frozen=True)
class _Spec:
    name: str
    key: str
    hint: Any
    flatten: bool | tuple[str, ...]
    omit: str | Callable[[Any], bool] | None
    missing: Any
    missing_from: Callable[[Mapping[str, Any]], Any] | None
    write: bool


@functools.cache
def _specs(cls: Any) -> tuple[_Spec, ...]:
    hints = typing.get_type_hints(cls)
    specs = []
    for item in dataclasses.fields(cls):
        options = dict(item.metadata.get("json", {}))
        missing = options.get("missing", _NO_VALUE)
        if missing is _NO_VALUE and item.default is not dataclasses.MISSING:
            missing = item.default
        if missing is _NO_VALUE and item.default_factory is not dataclasses.MISSING:
            missing = item.default_factory()
        specs.append(
            _Spec(
                name=item.name,
                key=options.get("key") or item.name,
                hint=hints[item.name],
                flatten=options.get("flatten", False),
                omit=options.get("omit"),
                missing=missing,
                missing_from=options.get("missing_from"),
                write=options.get("write", True),
            )
        )
    return tuple(specs)


def _own_codec(cls: type) -> bool:
    """Whether the class writes and reads itself (``to_dict``/``from_dict`` not inherited from JsonDataclass)."""
    return "to_dict" in _defined(cls) and not issubclass(cls, JsonDataclass)


def _defined(cls: type) -> set[str]:
    return {name for klass in cls.__mro__ for name in vars(klass)}


# ---------------------------------------------------------------------------- writing


def to_json(value: Any) -> Any:
    """The JSON value of ``value`` (dataclasses by their fields' options; mapping keys as strings)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        if _own_codec(type(value)):
            return value.to_dict()  # type: ignore[attr-defined]
        return to_json_dict(value)
    if isinstance(value, enum.Enum):
        return to_json(value.value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Mapping):
        return {_key(k): to_json(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return [to_json(v) for v in value]
    return value


def _key(key: Any) -> str:
    if isinstance(key, enum.Enum):
        key = key.value
    if isinstance(key, np.generic):
        key = key.item()
    return key if isinstance(key, str) else str(key)


def to_json_dict(obj: Any) -> dict[str, Any]:
    """The JSON object of one dataclass instance: its fields (by their options), then its extra keys, in order."""
    data: dict[str, Any] = {}
    for spec in _specs(typing.cast(Any, type(obj))):
        value = getattr(obj, spec.name)
        if not spec.write or _omitted(spec, obj, value):
            continue
        if spec.flatten:
            encoded = _encode(spec.hint, value)
            keys = list(encoded) if spec.flatten is True else list(spec.flatten or ())
            data.update({k: encoded[k] for k in keys})
        else:
            data[spec.key] = _encode(spec.hint, value)
    for name in getattr(type(obj), "__json_extra__", ()):
        data[name] = to_json(getattr(obj, name))
    order = getattr(type(obj), "__json_order__", None)
    if order is not None:
        data = {k: data[k] for k in order if k in data} | {k: v for k, v in data.items() if k not in order}
    return data


def _encode(hint: Any, value: Any) -> Any:
    """A field's JSON value; a value typed ``Any`` (free-form settings, a config's dict) is JSON already and
    is written as it is (a mapping of them: copied)."""
    args = typing.get_args(hint)
    if hint is Any:
        return value
    if typing.get_origin(hint) in (dict, Mapping) and len(args) == 2 and args[1] is Any and value is not None:
        return {_key(k): v for k, v in value.items()}
    return to_json(value)


def _omitted(spec: _Spec, obj: Any, value: Any) -> bool:
    if spec.omit is None:
        return False
    if spec.omit == "none":
        return value is None
    if callable(spec.omit):
        return bool(spec.omit(obj))
    raise ValueError(f"unknown omit option {spec.omit!r} of field {spec.name}")


# ---------------------------------------------------------------------------- reading


def from_json(tp: Any, data: Any) -> Any:
    """The value of type ``tp`` whose JSON value is ``data`` (KeyError, TypeError or ValueError when it is not one)."""
    if tp is Any or tp is object:
        return data
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (Union, types.UnionType):
        if data is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        if len(options) != 1:
            raise TypeError(f"cannot read a value of the union {tp}")
        return from_json(options[0], data)
    if origin is typing.Literal:
        if data not in args:
            raise ValueError(f"{data!r} is not one of {args}")
        return data
    if origin is tuple:
        items = _sequence(data, tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(from_json(args[0], v) for v in items)
        if args and len(items) != len(args):
            raise ValueError(f"expected {len(args)} values, got {len(items)}")
        return tuple(from_json(a, v) for a, v in zip(args, items, strict=False)) if args else tuple(items)
    if origin in (list, Sequence, typing.Sequence) or tp is list:
        item = args[0] if args else Any
        values = [from_json(item, v) for v in _sequence(data, tp)]
        return values if origin is list or tp is list else tuple(values)
    if origin in (dict, Mapping, typing.Mapping) or tp is dict:
        if not isinstance(data, Mapping):
            raise TypeError(f"expected a JSON object, got {type(data).__name__}")
        key_type, value_type = args if args else (Any, Any)
        return {_read_key(key_type, k): from_json(value_type, v) for k, v in data.items()}
    if isinstance(tp, type):
        return _scalar_or_class(tp, data)
    raise TypeError(f"cannot read a value of type {tp}")


def _sequence(data: Any, tp: Any) -> Sequence[Any]:
    if not isinstance(data, (list, tuple)):
        raise TypeError(f"expected a JSON array for {tp}, got {type(data).__name__}")
    return data


def _read_key(tp: Any, key: Any) -> Any:
    if tp is int:
        return int(key)
    if tp is float:
        return float(key)
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return tp(key)
    return key if tp is Any else str(key)


def _scalar_or_class(tp: type, data: Any) -> Any:
    if issubclass(tp, enum.Enum):
        return tp(data)
    if tp is bool:
        return bool(data)
    if tp in (int, float, str):
        if isinstance(data, (Mapping, list, tuple)) or data is None:
            raise TypeError(f"expected {tp.__name__}, got {type(data).__name__}")
        return tp(data)
    if dataclasses.is_dataclass(tp):
        if _own_codec(tp):
            return tp.from_dict(data)  # type: ignore[attr-defined]
        return from_json_dict(tp, data)
    raise TypeError(f"cannot read a value of type {tp.__name__}")


def from_json_dict(cls: type[T], data: Any) -> T:
    """The instance of dataclass ``cls`` whose JSON object is ``data`` (:func:`to_json_dict`'s inverse)."""
    if not isinstance(data, Mapping):
        raise TypeError(f"{cls.__name__} must be a JSON object, got {type(data).__name__}")
    values: dict[str, Any] = {}
    for spec in _specs(typing.cast(Any, cls)):
        if spec.flatten:
            values[spec.name] = _read_flattened(spec, data)
        elif spec.write and spec.key in data:
            values[spec.name] = from_json(spec.hint, data[spec.key])
        elif spec.missing_from is not None:
            values[spec.name] = spec.missing_from(data)
        elif spec.missing is not _NO_VALUE:
            values[spec.name] = copy.copy(spec.missing)
        else:
            raise KeyError(spec.key)
    return cls(**values)


def _read_flattened(spec: _Spec, data: Mapping[str, Any]) -> Any:
    if spec.flatten is True:
        return from_json(spec.hint, data)
    value_type = typing.get_args(spec.hint)[1] if typing.get_args(spec.hint) else Any
    return {key: from_json(value_type, data[key]) for key in tuple(spec.flatten or ())}


class JsonDataclass:
    """Mixin for a frozen dataclass: ``to_dict()`` and ``from_dict()`` by this module."""

    def to_dict(self) -> dict[str, Any]:
        """This value's JSON object."""
        return to_json_dict(self)

    @classmethod
    def from_dict(cls: type[T], data: Mapping[str, Any]) -> T:
        """The value of a JSON object written by ``to_dict`` (or by an older version)."""
        return from_json_dict(cls, data)


__all__ = ["JsonDataclass", "from_json", "from_json_dict", "json_options", "to_json", "to_json_dict"]
