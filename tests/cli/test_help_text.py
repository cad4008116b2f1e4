"""Every ``ghostshell`` option says what it does (issue 45, item 4), checked on the parsers themselves.

A new user found ``--mode`` with no help line, ``ghostshell log decode --help`` with no description and
``--out OUT`` beside ``--out DIR``. Each command's parser is built as ``ghostshell`` builds it
(:func:`host.cli.build_parser` with that command chosen), subcommands' actions included; ``board``
is left out: its parser is ``python -m firmware_sim``'s, in another process.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator

import pytest

from host.cli import COMMANDS, build_parser

COMMAND_NAMES = [c for c in COMMANDS if c != "board"]


def _parsers(parser: argparse.ArgumentParser, path: str) -> Iterator[tuple[str, argparse.ArgumentParser]]:
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, f"{path} {name}")


def _command_parsers(command: str) -> list[tuple[str, argparse.ArgumentParser]]:
    top = build_parser([command])
    subs = next(a for a in top._actions if isinstance(a, argparse._SubParsersAction))
    return list(_parsers(subs.choices[command], command))


@pytest.mark.parametrize("command", COMMAND_NAMES)
def test_every_option_has_help_and_every_parser_a_description(command: str) -> None:
    missing = []
    for path, parser in _command_parsers(command):
        if not parser.description:
            missing.append(f"ghostshell {path}: no description")
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                missing += [f"ghostshell {path} {c.dest}: no help" for c in action._choices_actions if not c.help]
            elif not action.help:  # (argparse.SUPPRESS: a hidden option, on purpose)
                missing.append(f"ghostshell {path} {'/'.join(action.option_strings) or action.dest}: no help")
    assert not missing, "\n".join(missing)


@pytest.mark.parametrize("command", COMMAND_NAMES)
def test_out_is_a_dir_or_a_file(command: str) -> None:
    for path, parser in _command_parsers(command):
        for action in parser._actions:
            if "--out" in action.option_strings:
                assert action.metavar in ("DIR", "FILE"), f"ghostshell {path} --out {action.metavar or action.dest.upper()}"
