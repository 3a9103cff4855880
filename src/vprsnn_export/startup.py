"""Ctrl-C while the command loads: exit 130 with one line, as during the command itself, not a traceback.

Started as the command, the package's ``__init__`` installs :func:`interrupted_while_loading` as the SIGINT handler
before it imports anything else; ``__main__`` keeps it while the command's module loads, then :func:`end_guard` hands
SIGINT back to Python (an ignored SIGINT stays ignored). This module imports nothing ``signal`` does not.
"""

from __future__ import annotations

import os
import signal
import sys

COMMAND = "vprsnn-export"
PACKAGE = "vprsnn_export"
EXIT_INTERRUPTED = 128 + signal.SIGINT


def interrupted_while_loading(signum: int, frame: object) -> None:
    """The SIGINT handler while loading: ``error: interrupted`` on stderr, exit code 130."""
    print("error: interrupted", file=sys.stderr)
    raise SystemExit(EXIT_INTERRUPTED)


def started_as_command(argv0: str, orig_argv: list[str] | tuple[str, ...]) -> bool:
    """Whether the script is ``vprsnn-export`` or ``orig_argv`` (``sys.orig_argv``) runs ``-m vprsnn_export``."""
    if os.path.basename(argv0) == COMMAND:
        return True
    args = list(orig_argv[1:])
    index = 0
    while index < len(args):
        arg = args[index]
        if arg == "-m" or (arg.startswith("-m") and not arg.startswith("--")):
            module = arg[2:] or (args[index + 1] if index + 1 < len(args) else "")
            return module in (PACKAGE, f"{PACKAGE}.__main__")
        if not arg.startswith("-") or arg in ("-", "--") or arg.startswith("-c"):
            return False  # a script, stdin or -c code runs: not the command
        index += 2 if arg in ("-X", "-W") else 1
    return False


def install_guard() -> None:
    """Make SIGINT :func:`interrupted_while_loading`, unless it is ignored or handled by the program already."""
    if signal.getsignal(signal.SIGINT) in (signal.default_int_handler, interrupted_while_loading):
        try:
            signal.signal(signal.SIGINT, interrupted_while_loading)
        except ValueError:  # not the main thread: its program owns the signals
            pass


class InterruptsHeld:
    """``with InterruptsHeld():`` a SIGINT inside the block is only noted, and handed to the handler it replaced
    when the block ends.

    For torch's import: an exception raised inside its C++ start-up (a Python callback under pybind11) aborts the
    process instead of exiting 130 with one line. A plain class, not contextlib: this module comes in before
    anything else. Outside the main thread, or with SIGINT ignored, a no-op."""

    def __enter__(self) -> None:
        self.noted = False
        self.previous = signal.getsignal(signal.SIGINT)
        if callable(self.previous):
            try:
                signal.signal(signal.SIGINT, self._note)
            except ValueError:  # not the main thread: its program owns the signals
                self.previous = None

    def _note(self, signum: int, frame: object) -> None:
        self.noted = True

    def __exit__(self, *exc: object) -> None:
        if callable(self.previous):
            signal.signal(signal.SIGINT, self.previous)
            if self.noted:
                self.previous(signal.SIGINT, None)


def end_guard() -> None:
    """Hand SIGINT back to Python's KeyboardInterrupt, if the guard holds it."""
    if signal.getsignal(signal.SIGINT) is interrupted_while_loading:
        signal.signal(signal.SIGINT, signal.default_int_handler)
