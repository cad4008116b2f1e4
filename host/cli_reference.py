"""``python -m host.cli_reference [--out FILE] [--check]``: write ``docs/cli.md``, the CLI reference,
from the argument parsers themselves.

Each ``ghostshell`` command's parser is built exactly as ``ghostshell`` builds it
(:func:`host.cli.build_parser` with that command chosen, so its module's ``configure(parser)`` runs),
and its help is argparse's own ``format_help()`` at a fixed width (:data:`WIDTH` columns, whatever the
terminal), subcommands (``robots new``, ``log decode``, ...) included. ``ghostshell board`` hands its
arguments to ``python -m firmware_sim`` (:mod:`host.commands.board`); host never imports firmware_sim,
so that section is the board's own ``--help``, run as a subprocess the way the command runs it (with
``GHOSTSHELL_BOARD_PROG`` naming it ``ghostshell board``); ``ghostshell firmware build`` and ``targets``
are ``python -m firmware_sim.cfirmware``'s, shown the same way (``GHOSTSHELL_FIRMWARE_PROG``). The servo-bus
plant, ``python -m firmware_sim.plant`` (a test double, no ``ghostshell`` command), gets a section of its own,
its ``--help`` run as a subprocess too (:data:`PLANT_MODULE`). The page also carries the exit codes
(:data:`host.cli.EXIT_CODES`).

Written by hand (about 60 lines of glue): argparse renders every parser's help; the Markdown
generators on PyPI for argparse (``mkdocs-argparse``, ``argparse-help-markdown``) each render one
parser object, while ``ghostshell`` builds each command's parser on demand and the board's parser
lives in another process. ``tests/docs/test_cli_reference.py`` keeps the checked-in page current.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from host.cli import COMMANDS, EXIT_CODES, build_parser
from protocol.generated import check_or_write

__all__ = ["DOC", "PLANT_MODULE", "WIDTH", "render", "main"]

DOC = Path(__file__).resolve().parents[1] / "docs" / "cli.md"
#: help text width in columns (argparse reads COLUMNS through shutil.get_terminal_size)
WIDTH = 100
BOARD_PROG_ENV = "GHOSTSHELL_BOARD_PROG"  # firmware_sim.cli.PROG_ENV (not imported: host never imports firmware_sim)
#: the servo-bus plant's module (``python -m firmware_sim.plant``), documented beside the commands
PLANT_MODULE = "firmware_sim.plant"


@contextmanager
def _columns(width: int) -> Iterator[None]:
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(width)
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old


def _subparsers(parser: argparse.ArgumentParser) -> list[tuple[str, argparse.ArgumentParser]]:
    """(name, parser) of every subcommand of ``parser``, in declaration order."""
    out: list[tuple[str, argparse.ArgumentParser]] = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            out.extend(action.choices.items())
    return out


def _command_parser(name: str) -> argparse.ArgumentParser:
    """The parser of ``ghostshell NAME``, configured by its module as at run time."""
    top = build_parser([name])
    return dict(_subparsers(top))[name]


def _board_help() -> str:
    env = {**os.environ, "COLUMNS": str(WIDTH), BOARD_PROG_ENV: "ghostshell board"}
    proc = subprocess.run([sys.executable, "-m", "firmware_sim", "--help"], env=env, capture_output=True,
                          text=True, timeout=120, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"python -m firmware_sim --help exited {proc.returncode}: {proc.stderr.strip()}")
    return proc.stdout


def _firmware_help(action: str) -> str:
    """``ghostshell firmware ACTION --help`` for an action ``python -m firmware_sim.cfirmware`` runs
    (:data:`host.commands.firmware.PASSED_THROUGH`), run as a subprocess as the command runs it."""
    from host.commands.firmware import FIRMWARE_PROG_ENV

    env = {**os.environ, "COLUMNS": str(WIDTH), FIRMWARE_PROG_ENV: "ghostshell firmware"}
    proc = subprocess.run([sys.executable, "-m", "firmware_sim.cfirmware", action, "--help"], env=env,
                          capture_output=True, text=True, timeout=120, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"python -m firmware_sim.cfirmware {action} --help exited {proc.returncode}: "
                           f"{proc.stderr.strip()}")
    return proc.stdout


def _plant_help() -> str:
    """``python -m firmware_sim.plant --help``, run as a subprocess (host never imports firmware_sim)."""
    env = {**os.environ, "COLUMNS": str(WIDTH)}
    proc = subprocess.run([sys.executable, "-m", PLANT_MODULE, "--help"], env=env, capture_output=True, text=True,
                          timeout=120, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"python -m {PLANT_MODULE} --help exited {proc.returncode}: {proc.stderr.strip()}")
    return proc.stdout


def _firmware_passed_through() -> dict[str, str]:
    from host.commands.firmware import PASSED_THROUGH

    return PASSED_THROUGH


def _block(text: str) -> str:
    return "```text\n" + text.rstrip() + "\n```\n"


def _cell(text: str) -> str:
    """``text`` for a Markdown table cell (a bare ``|`` would end the cell)."""
    return text.replace("|", "\\|")


def _anchor(title: str) -> str:
    """The heading id mkdocs' toc extension gives ``title`` (lower case, spaces to hyphens)."""
    return title.lower().replace(" ", "-")


def render() -> str:
    """The whole page (Markdown)."""
    lines = ["<!-- GENERATED by `python -m host.cli_reference` from the argument parsers: do not edit. -->",
             "# CLI reference", "",
             "Every command's `--help`, generated from its argument parser (`host/cli.py` `COMMANDS`, each "
             "`host/commands/NAME.py` `configure(parser)`; `ghostshell board` is `python -m firmware_sim`, "
             "`firmware_sim/cli.py`). `ghostshell COMMAND --help` prints the same text.", "",
             "## Exit status", "",
             "Every command exits with one of these (`host.cli.EXIT_CODES`); `ghostshell vcan` passes its "
             "COMMAND's status through.", "",
             "| status | meaning |", "| --- | --- |"]
    lines += [f"| {code} | {_cell(meaning)} |" for code, meaning in EXIT_CODES.items()]
    lines += ["", "## Commands", "", "| command | what it does |", "| --- | --- |"]
    lines += [f"| [`{name}`](#{_anchor('ghostshell ' + name)}) | {_cell(help_text)} |"
              for name, (_, help_text) in COMMANDS.items()]
    lines.append("")
    with _columns(WIDTH):
        lines += ["## ghostshell", "", _block(build_parser([]).format_help())]
        for name, (_, help_text) in COMMANDS.items():
            lines += [f"## ghostshell {name}", "", help_text[:1].upper() + help_text[1:] + ".", ""]
            if name == "board":
                lines += ["Every argument goes to `python -m firmware_sim` unchanged; its help:", "",
                          _block(_board_help())]
                continue
            parser = _command_parser(name)
            lines.append(_block(parser.format_help()))
            for sub_name, sub in _subparsers(parser):
                passed = name == "firmware" and sub_name in _firmware_passed_through()
                lines += [f"### ghostshell {name} {sub_name}", "",
                          _block(_firmware_help(sub_name) if passed else sub.format_help())]
        lines += [f"## python -m {PLANT_MODULE}", "",
                  "The servo-bus plant: a robot's servos (and the IMU and ground-truth probe) answering on a pty, "
                  "a test double for the C firmware and the vendors' SDKs, not a `ghostshell` command "
                  "([reference](reference/plant.md)). Its help:", "",
                  _block(_plant_help())]
    return "\n".join(lines).rstrip() + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m host.cli_reference", description=(__doc__ or "").splitlines()[0])
    p.add_argument("--out", type=Path, default=DOC, help=f"the page to write (default {DOC})")
    p.add_argument("--check", action="store_true", help="exit 1 when the page differs from what the parsers give")
    args = p.parse_args(argv)
    return check_or_write({args.out: render()}, check=args.check, command="python -m host.cli_reference")

if __name__ == "__main__":
    sys.exit(main())
