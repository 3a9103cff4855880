"""Frozen dataclasses <-> JSON: written field by field, read back by dacite, typed, with one error naming the field.

``to_json(value)`` is the plain JSON value of ``value`` (dataclasses by ``to_dict``, mappings with string
keys, tuples as lists, numpy scalars and arrays as numbers and lists, paths as strings). ``JsonDataclass.from_dict`` reads
one back with dacite: every value is checked against its field's type hint (nested dataclasses,
``X | None``, tuples from JSON arrays, ``Mapping[int, X]`` from an object with string keys, a float from
an integer, numpy scalars as Python ones), and the first one that does not fit is one error naming its
field (``runs.n_queries: expected int, got 'many'``). ``Type.from_dict(json.loads(json.dumps(x.to_dict()))) == x``.

A field's JSON form is the field name and its value, unless its metadata
(``field(metadata=json_options(...))``) says otherwise:

* ``key``: another JSON key (``float_values`` is ``"float"``);
* ``flatten``: the value's keys sit in the parent object (a dataclass: its fields; a mapping:
  the keys ``flatten`` lists);
* ``omit``: ``"none"`` leaves the key out when the value is None; a function ``omit(obj)`` when it says so;
* ``missing`` / ``missing_from``: the value when a file lacks the key (older files), a constant or a
  function of the parent object's data; by default the field's own default, else the key is required;
* ``write=False``: never written (read from ``missing_from`` only).

A class may list computed keys written after its fields (``__json_extra__``: property names,
ignored on reading) and a key order (``__json_order__``). A dataclass that defines ``from_dict``
itself (the quantisation header) reads itself.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import re
import reprlib
import typing
from collections.abc import Callable, Mapping
from pathlib import PurePath
from typing import Any, TypeVar

import dacite
import numpy as np

from ..errors import InvalidValueError

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
    return {"json": dict(key=key, flatten=flatten, omit=omit, missing=missing, missing_from=missing_from, write=write)}


@functools.cache
def _options(item: dataclasses.Field[Any]) -> dict[str, Any]:
    options = {**json_options()["json"], **item.metadata.get("json", {})}
    return options | {"key": options["key"] or item.name}


def to_json(value: Any) -> Any:
    """The JSON value of ``value`` (dataclasses by their fields' options; mapping keys as strings)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return value.to_dict() if hasattr(value, "to_dict") else to_json_dict(value)
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    if isinstance(value, PurePath):
        return str(value)
    if isinstance(value, Mapping):
        return {k if isinstance(k, str) else str(to_json(k)): to_json(v) for k, v in value.items()}
    if isinstance(value, tuple | list):
        return [to_json(v) for v in value]
    return value


def to_json_dict(obj: Any) -> dict[str, Any]:
    """The JSON object of one dataclass instance: its fields (by their options), then its extra keys, in order."""
    data: dict[str, Any] = {}
    cls: Any = type(obj)
    for item in dataclasses.fields(obj):
        value, options = getattr(obj, item.name), _options(item)
        omit = options["omit"]
        if not options["write"] or (omit == "none" and value is None) or (callable(omit) and omit(obj)):
            continue
        encoded = _encode(_hints(cls)[item.name], value)
        flatten = options["flatten"]
        if flatten:
            data.update({k: encoded[k] for k in (encoded if flatten is True else flatten)})
        else:
            data[options["key"]] = encoded
    data.update({name: to_json(getattr(obj, name)) for name in getattr(cls, "__json_extra__", ())})
    order = getattr(cls, "__json_order__", ())
    return {k: data[k] for k in order if k in data} | {k: v for k, v in data.items() if k not in order}


_hints = functools.cache(typing.get_type_hints)


def _encode(hint: Any, value: Any) -> Any:
    """A field's JSON value; one typed ``Any`` (free-form settings, a config's dict) is JSON already and is
    written as it is (a mapping of them: copied)."""
    if hint is Any:
        return value
    if typing.get_origin(hint) is Mapping and typing.get_args(hint)[1] is Any and value is not None:
        return dict(value)
    return to_json(value)


def from_json_dict(cls: type[T], data: Any) -> T:
    """The instance of dataclass ``cls`` whose JSON object is ``data`` (:func:`to_json_dict`'s inverse); a
    dacite error naming the field when it is not one (:func:`describe` says it in one line)."""
    if not isinstance(data, Mapping):
        raise dacite.WrongTypeError(field_type=cls, value=data)
    try:
        values = {item.name: _read(item, data) for item in dataclasses.fields(typing.cast(Any, cls))}
    except KeyError as exc:  # a required key, a flattened one, or one a missing_from function reads
        raise dacite.MissingValueError(exc.args[0]) from None
    return dacite.from_dict(cls, {k: v for k, v in values.items() if v is not _NO_VALUE}, _CONFIG)


def _read(item: dataclasses.Field[Any], data: Mapping[str, Any]) -> Any:
    """A field's JSON value in its parent object ``data`` (_NO_VALUE: the field's default)."""
    options = _options(item)
    flatten, key = options["flatten"], options["key"]
    if flatten:
        return data if flatten is True else {k: data[k] for k in flatten}
    if options["write"] and key in data:
        return data[key]
    if options["missing_from"] is not None:
        return options["missing_from"](data)
    if options["missing"] is not _NO_VALUE:
        return copy.copy(options["missing"])
    if item.default is dataclasses.MISSING and item.default_factory is dataclasses.MISSING:
        raise KeyError(key)
    return _NO_VALUE


def describe(exc: Exception) -> str:
    """One line saying what :func:`from_json_dict` found wrong: ``runs.n_queries: expected int, got 'many'``."""
    if isinstance(exc, dacite.WrongTypeError):
        tp = exc.field_type
        kind = tp.__name__ if isinstance(tp, type) else re.sub(r"\b(\w+\.)+", "", str(tp))  # Mapping[int, float]
        return f"{exc.field_path or 'the value'}: expected {kind}, got {reprlib.repr(exc.value)}"
    if isinstance(exc, dacite.MissingValueError):
        return f"{exc.field_path}: missing"
    return " ".join(str(exc).split())


@functools.cache
def _reader(tp: Any) -> Callable[[Any], Any] | None:
    """How dacite turns JSON into a value of type ``tp`` before checking it (None: as it is)."""
    if isinstance(tp, type) and issubclass(tp, JsonDataclass):
        return functools.partial(from_json_dict, tp)
    if isinstance(tp, type) and dataclasses.is_dataclass(tp) and hasattr(tp, "from_dict"):
        return typing.cast(Any, tp).from_dict
    if tp is float:  # an integer or numpy number as a float, as Python's float(x)
        return lambda data: float(data) if isinstance(data, int | np.number) else data
    if tp is int:
        return lambda data: int(data) if isinstance(data, np.integer) else data
    if typing.get_origin(tp) in (tuple, Mapping):
        return functools.partial(_collection, tp)
    return None


def _collection(tp: Any, data: Any) -> Any:
    """A JSON array as a tuple, a JSON object as a mapping (``Mapping[int, X]``: its keys as integers, left as they
    are when they are not: dacite names the field); anything else (a string, a number) is a WrongTypeError."""
    if typing.get_origin(tp) is tuple and isinstance(data, list | tuple):
        return tuple(data)
    if typing.get_origin(tp) is Mapping and isinstance(data, Mapping):
        try:
            return {int(k): v for k, v in data.items()} if typing.get_args(tp)[0] is int else data
        except (TypeError, ValueError):
            return data
    raise dacite.WrongTypeError(field_type=tp, value=data)


class _Readers(dict[Any, Any]):
    """dacite's type hooks, by :func:`_reader` (dacite asks ``tp in hooks``, then ``hooks[tp]``)."""

    def __contains__(self, tp: object) -> bool:
        return _reader(tp) is not None

    def __getitem__(self, tp: Any) -> Any:
        return _reader(tp)


_CONFIG = dacite.Config(type_hooks=_Readers())
#: What reading a malformed JSON value raises (the hooks and ``missing_from`` functions included).
READ_ERRORS = (dacite.DaciteError, KeyError, TypeError, ValueError, AttributeError)


class JsonDataclass:
    """Mixin for a frozen dataclass: ``to_dict()`` and ``from_dict()`` by this module."""

    def to_dict(self) -> dict[str, Any]:
        return to_json_dict(self)

    @classmethod
    def from_dict(cls: type[T], data: Mapping[str, Any]) -> T:
        """The value of a JSON object written by ``to_dict`` (or by an older version); InvalidValueError
        naming the field when it is not one."""
        try:
            return from_json_dict(cls, data)
        except READ_ERRORS as exc:
            raise InvalidValueError(f"malformed {cls.__name__} ({describe(exc)})") from None


__all__ = ["READ_ERRORS", "JsonDataclass", "describe", "from_json_dict", "json_options", "to_json", "to_json_dict"]
