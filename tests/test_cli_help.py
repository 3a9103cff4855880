"""Every subcommand's --help shows each option's default (every default that is not None, False or empty)."""

from __future__ import annotations

import argparse

import pytest

from vprsnn_export.cli import build_parser, command_names


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser(None)
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


@pytest.mark.parametrize("name", command_names())
def test_help_shows_every_default(name):
    sub = _subparsers()[name]
    text = " ".join(sub.format_help().split())
    missing = []
    for action in sub._actions:
        default = action.default
        if not action.option_strings or action.help == argparse.SUPPRESS:
            continue
        if default in (None, False, [], ()) or default is argparse.SUPPRESS:
            continue
        shown = " ".join(str(default).split())
        if f"default: {shown}" not in text and f"default {shown}" not in text:
            missing.append(f"{'/'.join(action.option_strings)}={shown!r}")
    assert not missing, f"{name} --help hides the default of {', '.join(missing)}"


@pytest.mark.parametrize("name", command_names())
def test_every_command_takes_threads(name):
    options = {s for a in _subparsers()[name]._actions for s in a.option_strings}
    assert "--threads" in options
