"""Expected errors: one clear message for the user, no traceback, a non-zero exit code."""

from __future__ import annotations

from pathlib import Path

EXIT_BAD_INPUT = 2
EXIT_CHECK_FAILED = 1


class VprError(Exception):
    """An expected failure caused by the user's input (file, option, data).

    The CLI prints ``error: <message>`` and exits with ``exit_code``.
    """

    exit_code: int = EXIT_BAD_INPUT

    def __init__(self, message: str, path: str | Path | None = None) -> None:
        self.path = None if path is None else Path(path)
        super().__init__(f"{path}: {message}" if path is not None else message)


class DataError(VprError):
    """A missing, unreadable or malformed image, manifest or selection."""


class ModelFileError(VprError):
    """A missing, truncated or invalid checkpoint, fixed-point model or exported file."""


class InvalidValueError(VprError, ValueError):
    """An unsupported value: a command-line option, a library argument or a config setting.

    The message names what was given (the option, argument or config key) and what is allowed.
    It is also a ``ValueError``, so callers that caught the bare ``ValueError`` the library once
    raised for a bad argument still catch it.
    """
