"""Batch chat files: user turns (``--turns``) or assistant replies (``--replies``).

Blocks are separated by a line holding only ``---``. A separator may carry
options for the block that follows it: ``--- interrupt-after 1.5`` interrupts
that block's turn 1.5 s (board time) after it started, as an external event
would; ``--- task 9`` (``ghostshell eval --replies`` only: ``parse_blocks(text,
options=("task",))``) names the task the reply answers. A separator on the first
line only sets options for the first block. Leading and trailing blank lines of a
block are dropped; empty blocks are skipped.

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
    task: int | None = None  # ``--- task N`` (eval --replies)


_USAGE = {"interrupt-after": "'--- interrupt-after SECONDS'", "task": "'--- task N'"}


def _options(text: str, lineno: int, allowed: tuple[str, ...]) -> dict[str, float | int]:
    words = text.split()
    expected = " or ".join(_USAGE[k] for k in allowed)
    found: dict[str, float | int] = {}
    for key, value in zip(words[::2], words[1::2] if len(words) % 2 == 0 else [*words[1::2], ""]):
        if key not in allowed:
            raise ScriptError(f"line {lineno}: unknown separator option {text!r}; expected {expected}")
        if key in found:
            raise ScriptError(f"line {lineno}: {key} given twice")
        if key == "task":
            if not value.isdigit() or int(value) < 1:
                raise ScriptError(f"line {lineno}: task needs a task number (1, 2, ...), got {value!r}")
            found[key] = int(value)
            continue
        try:
            seconds = float(value)
        except ValueError:
            raise ScriptError(f"line {lineno}: interrupt-after needs seconds, got {value!r}") from None
        if not math.isfinite(seconds) or seconds < 0:
            raise ScriptError(f"line {lineno}: interrupt-after must be >= 0 seconds, got {value!r}")
        found[key] = seconds
    return found


def parse_blocks(text: str, options: tuple[str, ...] = ("interrupt-after",)) -> list[Block]:
    """Split a batch file into blocks (see the module docstring); ``options``: the separator options allowed."""
    blocks: list[Block] = []
    current: list[str] = []
    opts: dict[str, float | int] = {}
    start = 1

    def flush() -> None:
        body = "\n".join(current).strip("\n")
        if body.strip():
            after = opts.get("interrupt-after")
            task = opts.get("task")
            blocks.append(Block(body, None if after is None else float(after), start,
                                None if task is None else int(task)))

    for i, line in enumerate(text.splitlines(), start=1):
        m = _SEP.match(line)
        if m is None:
            current.append(line)
            continue
        flush()
        current, opts, start = [], _options(m.group("opts") or "", i, options), i + 1
    flush()
    return blocks
