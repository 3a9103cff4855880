"""The ``vprsnn-export`` command's entry point (also ``python -m vprsnn_export``).

The guard of :mod:`vprsnn_export.startup` stands until the command line and the command's module are imported.
"""

import atexit
import errno
import os
import signal
import sys

from .startup import EXIT_INTERRUPTED, end_guard, install_guard

install_guard()

from .cli import import_command, main  # noqa: E402  (imported under the guard above)

import_command(sys.argv[1:])  # the command's module loads under the guard too (torch: set_threads)

end_guard()


EXIT_BROKEN_PIPE = 128 + signal.SIGPIPE  # what a shell reports for a writer killed by SIGPIPE (`| head`)
EXIT_WRITE_ERROR = 1


def run() -> None:
    """``main()``; a standard output that cannot be written (a closed pipe, a full device) ends the run quietly.

    Once ``main()`` has returned, SIGINT is ignored (the first exit handler): a Ctrl-C during torch's and numba's
    clean-up would print a traceback or kill the process by the signal. Not before: a program that calls ``run()``
    and catches its SystemExit keeps its own handler (its children would inherit an ignored SIGINT)."""
    try:
        code = main()
        sys.stdout.flush()
        atexit.register(signal.signal, signal.SIGINT, signal.SIG_IGN)  # a late Ctrl-C cannot break the exit
    except KeyboardInterrupt:  # between the guard's end and main's own handler
        print("error: interrupted", file=sys.stderr)
        code = EXIT_INTERRUPTED
    except BrokenPipeError:
        _silence_stdout()
        code = EXIT_BROKEN_PIPE
    except OSError as exc:
        if exc.errno not in (errno.ENOSPC, errno.EIO, errno.EFBIG):
            raise
        _silence_stdout()
        print(f"error: cannot write the standard output ({exc.strerror})", file=sys.stderr)
        code = EXIT_WRITE_ERROR
    sys.exit(code)


def _silence_stdout() -> None:
    """Point stdout at /dev/null so that Python's own flush at exit does not fail a second time."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)


if __name__ == "__main__":
    run()
