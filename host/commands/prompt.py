"""``ghostshell prompt``: print the system prompt for the mounted functions."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Iterable
from typing import Any

from host.commands.modearg import add_mode_argument
from host.commands.errors import print_error
from host.commands.robotarg import add_robot_argument, robot_from_args


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the prompt options."""
    parser.add_argument("--format", choices=("code", "xml"), default="code", help="Python stubs or XML tokens")
    add_mode_argument(parser)
    parser.add_argument("--text-first-class", action="store_true", help="speech blocks on the main channel")
    parser.add_argument(
        "--interface",
        default=None,
        metavar="MODULE:ATTR",
        help="callable returning a Registry, a list of Modules or a dict {module: interface class} "
        "(default: the --robot's interface; e.g. host.testing.quadruped:modules)",
    )
    add_robot_argument(parser)
    parser.add_argument("--vocabulary", default=None, metavar="NAME",
                        help="which of the robot's vocabularies the prompt shows (default: the robot's; the mapper "
                             "accepts all; ghostshell robots show NAME lists them)")
    parser.add_argument("--skills", default=None, metavar="FILE", help="skill memory JSON file to list")


def load_interface(spec: str) -> Any:
    """Import ``MODULE:ATTR`` and return the attribute (called if callable)."""
    mod_name, _, attr = spec.partition(":")
    obj = getattr(importlib.import_module(mod_name), attr or "modules")
    return obj() if callable(obj) else obj


def build_registry(spec: str | None, vocabulary: str | None = None, robot: Any = None) -> tuple[Any, str]:
    """A registry with the interface mounted (``spec``, else ``robot``'s, else the default robot's), and
    the interface actually used."""
    from host.shell.registry import Registry

    if spec is None:
        from host.runtime.binding import signature_registry
        from robots.registry import load_robot

        bot = robot if robot is not None else load_robot()
        vocab = vocabulary or bot.interface.default
        return signature_registry(bot, vocab), f"{bot.name} ({vocab} vocabulary)"
    obj = load_interface(spec)
    if isinstance(obj, Registry):
        return obj, spec
    if isinstance(obj, dict):  # {module name: interface class}, e.g. from robots/ (which cannot import host)
        from host.shell.types import Module

        return Registry([Module.interface_only(n, iface) for n, iface in obj.items()]), spec
    return Registry(list(obj if isinstance(obj, Iterable) else [obj])), spec


def main(args: argparse.Namespace) -> int:
    """Print the prompt; returns 2 on a bad interface."""
    from host.shell.prompt import render_prompt
    from host.shell.skills import SkillStore

    robot = None
    if args.interface is None:
        robot = robot_from_args(args, "prompt")
        if isinstance(robot, int):
            return robot
    try:
        registry, _used = build_registry(args.interface, args.vocabulary, robot)
    except (ImportError, AttributeError, ValueError, TypeError) as exc:
        print_error("prompt", f"cannot load interface {args.interface!r}: {exc}")
        return 2
    from host.shell.skills import SkillError

    try:
        skills = SkillStore(args.skills) if args.skills else None
    except SkillError as exc:
        print_error("prompt", str(exc))
        return 2
    sys.stdout.write(render_prompt(registry, format=args.format, mode=args.mode,
                                   text_first_class=args.text_first_class, skills=skills))
    return 0
