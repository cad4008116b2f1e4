"""The events of :class:`host.shell.parser.FunctionTokenParser` and its error, with where they happened.

A parse yields, in stream order: :class:`Text` (speech), :class:`StartTag` / :class:`EndTag` /
:class:`EmptyTag` (function tokens) and, in lenient mode, :class:`ParseWarning` (a recovery). Strict
mode raises :class:`ParseError`. Positions are in the line-ending-normalised stream (see the parser's
module docstring). Importable from :mod:`host.shell.parser` too.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TypeAlias

__all__ = ["EmptyTag", "EndTag", "Event", "ParseError", "ParseWarning", "Position", "StartTag", "Text"]


@dataclass(frozen=True, slots=True)
class Position:
    """A place in the (line-ending-normalised) input: 1-based line and column, 0-based offset."""

    line: int = 1
    column: int = 1
    offset: int = 0

    def __str__(self) -> str:
        return f"line {self.line}, column {self.column}"


_NOPOS = Position()


@dataclass(frozen=True, slots=True)
class StartTag:
    """An AFToken ``<name a="v">``; ``attrs`` values have references resolved.

    ``refused`` (lenient mode) says why the call must not run (a duplicated attribute), or is None.
    """

    name: str
    attrs: dict[str, str]
    pos: Position = field(default=_NOPOS, compare=False)
    refused: str | None = field(default=None, compare=False)


@dataclass(frozen=True, slots=True)
class EndTag:
    """An RFToken ``</name>``."""

    name: str
    pos: Position = field(default=_NOPOS, compare=False)


@dataclass(frozen=True, slots=True)
class EmptyTag:
    """An SCFToken ``<name a="v"/>``; ``refused`` as for :class:`StartTag`."""

    name: str
    attrs: dict[str, str]
    pos: Position = field(default=_NOPOS, compare=False)
    refused: str | None = field(default=None, compare=False)


@dataclass(frozen=True, slots=True)
class Text:
    """Character data (FChar, resolved FRef, CDATA content); adjacent pieces within a feed are merged."""

    text: str
    pos: Position = field(default=_NOPOS, compare=False)


@dataclass(frozen=True, slots=True)
class ParseWarning:
    """A recovery made in lenient mode (the input was malformed at ``pos``)."""

    message: str
    pos: Position = field(default=_NOPOS, compare=False)


Event: TypeAlias = StartTag | EndTag | EmptyTag | Text | ParseWarning


class ParseError(Exception):
    """Malformed (or, at ``close()``, incomplete) input in strict mode.

    ``line``/``column`` (1-based) and ``offset`` (0-based) locate the problem; ``incomplete`` is True
    when the stream ended inside a token or element rather than containing a malformed one;
    ``events`` holds the events the failing ``feed``/``close`` call completed before the error, so
    nothing parsed is lost.
    """

    def __init__(
        self,
        message: str,
        line: int = 1,
        column: int = 1,
        offset: int = 0,
        *,
        incomplete: bool = False,
        events: list[Event] | None = None,
    ) -> None:
        super().__init__(f"{message} (line {line}, column {column}, offset {offset})")
        self.message = message
        self.line = line
        self.column = column
        self.offset = offset
        self.incomplete = incomplete
        self.events: list[Event] = events if events is not None else []
