"""Name -> entry registries: the project's extension points (targets, strategies, channels, estimators, rules).

Each extension point is one :class:`Registry`, filled where the entries are defined, one
``register`` line per entry. Every list of names, default, help text and report table
is generated from it (``names()``, in registration order), and an unknown name is one
:class:`~vprsnn_export.errors.InvalidValueError` that lists the known ones. The
walkthrough (one new file and one registry line per addition) is in docs/architecture.md.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Generic, Protocol, TypeVar

from .errors import InvalidValueError


class Named(Protocol):
    """An entry: anything with a ``name``."""

    @property
    def name(self) -> str: ...


EntryT = TypeVar("EntryT", bound=Named)


class Registry(Generic[EntryT]):
    """An ordered name -> entry map; ``kind`` names the setting in error messages (e.g. "--targets")."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self._entries: dict[str, EntryT] = {}

    def register(self, entry: EntryT) -> EntryT:
        """Add ``entry`` under its name (ValueError when the name is taken); returns it."""
        if entry.name in self._entries:
            raise InvalidValueError(f"{self.kind}: {entry.name!r} is registered already")
        self._entries[entry.name] = entry
        return entry

    def unregister(self, name: str) -> EntryT:
        """Remove and return an entry (a test's toy entry)."""
        return self._entries.pop(self.get(name).name)

    def get(self, name: str) -> EntryT:
        """The entry of ``name``; InvalidValueError listing the known names otherwise."""
        try:
            return self._entries[name]
        except (KeyError, TypeError):
            raise InvalidValueError(f"{self.kind}: unknown {name!r}; choose from {', '.join(self.names())}") from None

    def names(self) -> tuple[str, ...]:
        """Every name, in registration order (the default order of every list)."""
        return tuple(self._entries)

    def values(self) -> tuple[EntryT, ...]:
        return tuple(self._entries.values())

    def choices(self) -> str:
        """The names as a help text writes them: "a, b, c"."""
        return ", ".join(self.names())

    def parse_list(self, raw: str, option: str, *, allow_none: bool = False) -> tuple[str, ...]:
        """``"a,b"`` -> ("a", "b") (case and empty items ignored, duplicates dropped); "none" (when allowed) -> ().

        InvalidValueError naming ``option`` on an unknown name, or on nothing at all unless ``allow_none``.
        """
        names = tuple(dict.fromkeys(v.strip().lower() for v in raw.split(",") if v.strip()))
        unknown = [n for n in names if n not in self._entries and not (allow_none and n == "none")]
        if unknown or (not allow_none and not names):
            allowed = self.choices() + (" (or none)" if allow_none else "")
            raise InvalidValueError(f"{option} expects some of {allowed}, got {raw!r}")
        return tuple(n for n in names if n != "none")

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self._entries)


__all__ = ["Registry"]
