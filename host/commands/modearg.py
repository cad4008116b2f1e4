"""``--mode async-first|sync-first``: how a program's calls are scheduled (``run``, ``demo``, ``chat``,
``prompt``, ``mcp``, ``eval``), one definition so every command's help says the same
(:data:`host.shell.scheduler.MODES`; the system prompt explains the chosen one to the LLM)."""

from __future__ import annotations

import argparse

__all__ = ["MODE_HELP", "add_mode_argument"]

MODE_HELP = ("how calls are scheduled: async-first (default; calls on different modules run in parallel, "
             "<wait> says 'first ... then ...') or sync-first (one call after another in the order written, "
             "<async> runs its children in parallel); the system prompt explains it to the LLM")


def add_mode_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--mode`` (dest ``mode``, default ``"async-first"``)."""
    parser.add_argument("--mode", choices=("async-first", "sync-first"), default="async-first", help=MODE_HELP)
