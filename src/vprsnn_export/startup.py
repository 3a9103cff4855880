"""Ctrl-C while the command loads: exit 130 with one line, as during the command itself, not a traceback.

Started as ``vprsnn-export`` or ``python -m vprsnn_export``, the package's ``__init__`` installs
:func:`interrupted_while_loading` as the SIGINT handler before it imports anything else (an import
of the library in another program changes no handler); ``__main__`` keeps it while the command
line and the command's module load, then :func:`end_guard` hands SIGINT back to Python and
:func:`vprsnn_export.cli.main` turns an interrupt into the same line after cleaning up (torch and
numba load there, lazily: see :func:`vprsnn_export.cli.import_command`).
A SIGINT that was ignored when the process started (a job started in the background) stays ignored.
Only the interpreter's own start, before the package's first line runs, is outside the guard;
this module imports nothing that ``signal`` does not (no typing, no threading) to come in sooner.
torch loads later, when a command sets its threads: :class:`InterruptsHeld` keeps a Ctrl-C out of its
C++ start-up, and the command's handler turns it into the same line once torch is in.
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
    """Whether the process runs the command: its script is ``vprsnn-export``, or Python runs ``-m vprsnn_export``.

    ``orig_argv`` is Python's own command line (``sys.orig_argv``): its options are read up to the
    first that names what runs (``-m MODULE``, ``-c CODE``, a script); ``-X`` and ``-W`` take a value.
    """
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
    (Python's: KeyboardInterrupt) when the block ends.

    For torch's import after the guard: an exception raised inside its C++ start-up (a Python callback
    under pybind11) aborts the process with a C++ message instead of exiting 130 with one line; noted, it
    is raised after the import, where the command's own handler catches it. A plain class, not contextlib:
    this module comes in before anything else. Outside the main thread, or with SIGINT ignored, a no-op.
    """

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
