"""The `vprsnn-export` command: subcommands are the modules of :mod:`vprsnn_export.commands`."""

from __future__ import annotations

import argparse
import ast
import importlib
import importlib.util
import pkgutil
import re
import signal
import sys
import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from . import commands
from .errors import EXIT_BAD_INPUT, VprError
from .io.fileio import check_output_folder, output_lock
from .resources import set_memory_limit
from .startup import EXIT_INTERRUPTED
from .threads import set_threads
from .version import __version__

if TYPE_CHECKING:
    from _typeshed import SupportsWrite

NEGATIVE_VALUE = re.compile(r"^-\.?\d")  # "-2:2:0.1", "-0.5": a value, not an option


class DefaultsFormatter(argparse.HelpFormatter):
    """Help that appends ``(default: X)`` unless the help names a default already or there is none."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        no_default = default in (None, False, [], ()) or default is argparse.SUPPRESS or not action.option_strings
        if no_default or "default" in text.lower():  # named already: %(default)s included
            return text
        return f"{text} (default: %(default)s)" if text else "default: %(default)s"

    def _split_lines(self, text: str, width: int) -> list[str]:
        """Wrapped at spaces only: a path or name with hyphens (vprsnn-export) stays whole."""
        return textwrap.wrap(" ".join(text.split()), width, break_on_hyphens=False) or [""]


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``error: <problem>``, exit code 2) and :class:`DefaultsFormatter` help."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", DefaultsFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        print(f"error: {self.prog}: {message}", file=sys.stderr)
        raise SystemExit(EXIT_BAD_INPUT)

    def _print_message(self, message: str, file: SupportsWrite[str] | None = None) -> None:
        """argparse's, without its ``except OSError: pass`` (``__main__.run`` reports a failed write)."""
        if message:
            (file or sys.stderr).write(message)


def join_negative_values(argv: Sequence[str]) -> list[str]:
    """``--opt -2:2:0.1`` -> ``--opt=-2:2:0.1``: argparse would read a value starting with '-' as an option."""
    out: list[str] = []
    for token in argv:
        if out and out[-1].startswith("--") and "=" not in out[-1] and NEGATIVE_VALUE.match(token):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


def command_names() -> list[str]:
    return sorted(m.name for m in pkgutil.iter_modules(commands.__path__) if not m.name.startswith("_"))


def summary(name: str) -> str:
    """A command's one-line help: its module docstring's first line after "`vprsnn-export NAME`: ", not imported."""
    spec = importlib.util.find_spec(f"{commands.__name__}.{name}")
    source = Path(spec.origin).read_text(encoding="utf-8") if spec and spec.origin else ""
    first = (ast.get_docstring(ast.parse(source)) or "").split("\n")[0]
    return first.split(": ", 1)[-1].rstrip(".")


def chosen_command(argv: Sequence[str]) -> str | None:
    """The command ``argv`` names (its first word that is not an option), None for ``--help``/``--version``."""
    return next((token for token in argv if not token.startswith("-")), None)


def import_command(argv: Sequence[str]) -> None:
    """Import the module of the command ``argv`` names (``__main__`` calls this under its interrupt guard)."""
    name = chosen_command(argv)
    if name in command_names():
        importlib.import_module(f"{commands.__name__}.{name}")


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The parser for ``argv``: only the command it names imported (``argv=None``: every command's)."""
    parser = Parser(
        prog="vprsnn-export", description="STDP place-recognition SNNs: train, quantise, export, verify, localise."
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    chosen = None if argv is None else chosen_command(argv)
    for name in command_names():
        if argv is None or name == chosen:
            importlib.import_module(f"{commands.__name__}.{name}").register(subparsers)
        else:
            subparsers.add_parser(name, help=summary(name), add_help=False)
    return parser


class Terminated(BaseException):
    """SIGTERM, raised like an interrupt so that temp files are removed on the way out."""


def _terminate(signum: int, frame: object) -> None:
    raise Terminated


def main(argv: Sequence[str] | None = None) -> int:
    """Parse, run one command (its output locked); an expected error is one line and exit 2."""
    if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _terminate)
    try:
        argv = list(sys.argv[1:] if argv is None else argv)
        parser = build_parser(argv)
        try:
            args = parser.parse_args(join_negative_values(argv))
        except SystemExit as exc:  # --help, --version, or a one-line parse error already printed
            return exc.code if isinstance(exc.code, int) else EXIT_BAD_INPUT
        args.argv = argv
        args.threads = set_threads(getattr(args, "threads", None))
        set_memory_limit(getattr(args, "memory_limit", None))
        output = getattr(args, "report", None)
        output = getattr(args, "out", None) if output is None else output
        if output is not None and getattr(args, "output_kind", "folder") == "folder":
            check_output_folder(output)  # a file output (train) is checked by its command, against its inputs
        file_output = args.file_output(args) if hasattr(args, "file_output") else None  # evaluate --predictions, ...
        with output_lock(output), output_lock(file_output):
            return int(args.handler(args) or 0)
    except VprError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return exc.exit_code
    except PermissionError as exc:  # a file or folder the user may not read or write, wherever it is met
        where = exc.filename if exc.filename is not None else "a file"
        print(f"error: {where}: permission denied ({exc.strerror or exc})", file=sys.stderr)
        return EXIT_BAD_INPUT
    except (KeyboardInterrupt, Terminated) as exc:  # exit 128 + SIGINT or SIGTERM
        interrupted = isinstance(exc, KeyboardInterrupt)
        word, code = ("interrupted", EXIT_INTERRUPTED) if interrupted else ("terminated", 128 + signal.SIGTERM)
        print(f"error: {word}", file=sys.stderr)
        return code


if __name__ == "__main__":
    sys.exit(main())
