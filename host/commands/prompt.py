"""``ghostshell prompt``: print the system prompt for the mounted functions."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Iterable
from typing import Any

#: The default interface: CoCo, both vocabularies mounted, one shown (see host.coco.binding).
DEFAULT_INTERFACE = "coco"


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the prompt options."""
    parser.add_argument("--format", choices=("code", "xml"), default="code", help="Python stubs or XML tokens")
    parser.add_argument("--mode", choices=("async-first", "sync-first"), default="async-first")
    parser.add_argument("--text-first-class", action="store_true", help="speech blocks on the main channel")
    parser.add_argument(
        "--interface",
        default=None,
        metavar="MODULE:ATTR",
        help="callable returning a Registry, a list of Modules or a dict {module: interface class} "
        "(default: CoCo; e.g. host.shell.example:modules)",
    )
    parser.add_argument("--vocabulary", choices=("paper", "coco"), default="paper",
                        help="which of CoCo's two vocabularies the prompt shows (the mapper accepts both)")
    parser.add_argument("--skills", default=None, metavar="FILE", help="skill memory JSON file to list")


def load_interface(spec: str) -> Any:
    """Import ``MODULE:ATTR`` and return the attribute (called if callable)."""
    mod_name, _, attr = spec.partition(":")
    obj = getattr(importlib.import_module(mod_name), attr or "modules")
    return obj() if callable(obj) else obj


class _NoRobot:
    """A performer for prompt rendering only: the prompt never calls anything."""

    async def perform(self, behaviour: str, channel: str, args: dict[str, Any]) -> Any:
        raise RuntimeError("prompt rendering does not execute calls")

    async def reset(self, behaviour: str, channel: str) -> None:
        return None

    async def speak(self, text: str) -> Any:
        raise RuntimeError("prompt rendering does not execute calls")


def build_registry(spec: str | None, vocabulary: str = "paper") -> tuple[Any, str]:
    """A registry with the interface mounted, and the interface spec actually used."""
    from host.shell.registry import Registry

    if spec is None:
        from host.coco.binding import coco_registry

        return coco_registry(_NoRobot(), vocabulary), f"{DEFAULT_INTERFACE} ({vocabulary} vocabulary)"
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

    try:
        registry, _used = build_registry(args.interface, args.vocabulary)
    except (ImportError, AttributeError, ValueError, TypeError) as exc:
        print(f"ghostshell prompt: cannot load interface {args.interface!r}: {exc}", file=sys.stderr)
        return 2
    skills = SkillStore(args.skills) if args.skills else None
    sys.stdout.write(render_prompt(registry, format=args.format, mode=args.mode,
                                   text_first_class=args.text_first_class, skills=skills))
    return 0
