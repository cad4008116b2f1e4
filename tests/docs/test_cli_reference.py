"""docs/cli.md is what the argument parsers generate (``python -m host.cli_reference``), and it
covers every command and subcommand."""

from __future__ import annotations

import argparse
import re

from host.cli import COMMANDS
from host.cli_reference import DOC, PLANT_MODULE, render


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


def test_plant_section_gives_every_option_with_its_help() -> None:
    """``python -m firmware_sim.plant`` has a section (its own ``--help``, run as a subprocess), and every
    option of its parser carries help text that the page shows."""
    from firmware_sim.plant.server import parser

    text = DOC.read_text(encoding="utf-8")
    head = f"## python -m {PLANT_MODULE}\n"
    assert head in text
    section = text.split(head, 1)[1].split("\n## ", 1)[0]
    assert "usage: python -m firmware_sim.plant" in section
    flat = " ".join(section.split())
    options = [a for a in parser()._actions if a.option_strings]
    assert len(options) > 10
    for action in options:
        assert action.help and action.help != argparse.SUPPRESS, f"{action.option_strings}: no help text"
        for opt in action.option_strings:
            assert re.search(rf"^  (.*, )?{re.escape(opt)}\b", section, re.M), opt
        assert " ".join(action.help.split()) in flat, action.option_strings
