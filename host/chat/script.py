"""Batch chat files: user turns (``--turns``) or assistant replies (``--replies``).

Blocks are separated by a line holding only ``---``. A separator may carry an
option for the block that follows it: ``--- interrupt-after 1.5`` interrupts
that block's turn 1.5 s (board time) after it started, as an external event
would. A separator on the first line only sets options for the first block.
Leading and trailing blank lines of a block are dropped; empty blocks are
skipped.

Errors: :class:`ScriptError` with the line number for a malformed separator.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

_SEP = re.compile(r"^---(?:[ \t]+(?P<opts>.*?))?[ \t]*$")


class ScriptError(ValueError):
    """A malformed batch chat file."""


@dataclass(frozen=True)
class Block:
    """One user turn or one assistant reply."""

    text: str
    interrupt_after: float | None = None
    line: int = 1  # first line of the block (1-based)


def _options(text: str, lineno: int) -> float | None:
    words = text.split()
    if not words:
        return None
    if words[0] != "interrupt-after" or len(words) != 2:
        raise ScriptError(f"line {lineno}: unknown separator option {text!r}; expected '--- interrupt-after SECONDS'")
    try:
        value = float(words[1])
    except ValueError:
        raise ScriptError(f"line {lineno}: interrupt-after needs seconds, got {words[1]!r}") from None
    if not math.isfinite(value) or value < 0:
        raise ScriptError(f"line {lineno}: interrupt-after must be >= 0 seconds, got {words[1]!r}")
    return value


def parse_blocks(text: str) -> list[Block]:
    """Split a batch chat file into blocks (see the module docstring)."""
    blocks: list[Block] = []
    current: list[str] = []
    opts: float | None = None
    start = 1

    def flush() -> None:
        body = "\n".join(current).strip("\n")
        if body.strip():
            blocks.append(Block(body, opts, start))

    for i, line in enumerate(text.splitlines(), start=1):
        m = _SEP.match(line)
        if m is None:
            current.append(line)
            continue
        flush()
        current, opts, start = [], _options(m.group("opts") or "", i), i + 1
    flush()
    return blocks
