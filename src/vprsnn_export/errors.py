"""Expected errors: one clear message for the user, no traceback, a non-zero exit code."""

from __future__ import annotations

from pathlib import Path

EXIT_BAD_INPUT = 2
EXIT_CHECK_FAILED = 1
MAX_MESSAGE = 2000  # characters of one error message; a file's content never makes a longer line


def brief(value: object, width: int = 40) -> str:
    """``repr(value)`` cut to ``width`` characters (a long container by its type alone), for quoting a file's content."""
    text = repr(value) if not isinstance(value, list | tuple | dict) or len(value) < 64 else f"<{type(value).__name__}>"
    return text if len(text) <= width else f"{text[: width - 3]}..."


class VprError(Exception):
    """An expected failure caused by the user's input (file, option, data).

    The CLI prints ``error: <message>`` and exits with ``exit_code``.
    """

    exit_code: int = EXIT_BAD_INPUT

    def __init__(self, message: str, path: str | Path | None = None) -> None:
        self.path = None if path is None else Path(path)
        text = f"{path}: {message}" if path is not None else message
        text = " ".join(text.splitlines()) if "\n" in text else text
        cut = f"... ({len(text) - MAX_MESSAGE} characters cut)"
        super().__init__(text if len(text) <= MAX_MESSAGE else text[: MAX_MESSAGE - len(cut)] + cut)


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
