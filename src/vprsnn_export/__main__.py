"""The ``vprsnn-export`` command's entry point (also ``python -m vprsnn_export``).

A Ctrl-C while torch, numba and the rest load (a few seconds on a busy machine) exits with
code 130 and one line, like one during the command itself: the guard below stands until
the command line is imported, then Python's own handler is back and
:func:`vprsnn_export.cli.main` turns the interrupt into the same line after cleaning up.
"""

import signal
import sys


def _interrupted_while_loading(signum: int, frame: object) -> None:
    print("error: interrupted", file=sys.stderr)
    raise SystemExit(130)


signal.signal(signal.SIGINT, _interrupted_while_loading)

from .cli import import_command, main  # noqa: E402  (imported under the guard above)

import_command(sys.argv[1:])  # the command's module, torch and numba load under the guard too

signal.signal(signal.SIGINT, signal.default_int_handler)


def run() -> None:
    sys.exit(main())


if __name__ == "__main__":
    run()
