"""docs/cli.md is what the argument parsers generate (``python -m host.cli_reference``), and it
covers every command and subcommand."""

from __future__ import annotations

import re

from host.cli import COMMANDS
from host.cli_reference import DOC, render


def test_reference_is_current() -> None:
    assert DOC.read_text(encoding="utf-8") == render(), "stale: python -m host.cli_reference"


def test_every_command_and_subcommand_has_its_help() -> None:
    text = DOC.read_text(encoding="utf-8")
    for name in COMMANDS:
        assert re.search(rf"^## ghostshell {name}\n", text, re.M), name
        assert f"usage: ghostshell {name}" in text, name
    for sub in ("robots new", "robots list", "robots show", "robots path", "skills rm", "log decode", "firmware build",
                "firmware targets", "firmware check"):
        assert f"### ghostshell {sub}\n" in text and f"usage: ghostshell {sub}" in text, sub
    assert "--firmware {python,c,qemu" in text  # the board's own parser, through python -m firmware_sim --help
    assert "--target {native,mps2,stm32f4}" in text  # firmware build's own parser, through python -m firmware_sim.cfirmware
