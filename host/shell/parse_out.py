"""The output side of :class:`host.shell.parser.FunctionTokenParser`: events in order, text merged, open elements.

Speech arrives in pieces (:meth:`ParseOutput.text_at`) and leaves as one :class:`Text` event when
anything else is emitted or the feed ends (:meth:`ParseOutput.flush_text`); a tag event is appended
the moment the scanner completes it. :meth:`ParseOutput.start`/:meth:`ParseOutput.end` keep the stack
of open elements: a strict end-tag that does not close the innermost one raises
:class:`host.shell.parse_values._Malformed`; in lenient mode one naming an open ancestor closes the
inner elements first (an :class:`EndTag` and a :class:`ParseWarning` each) and one that closes
nothing is dropped with a warning. :attr:`ParseOutput.events` is replaced by the parser per call.
"""

from __future__ import annotations

from host.shell.parse_events import _NOPOS, EmptyTag, EndTag, Event, ParseWarning, Position, StartTag, Text
from host.shell.parse_values import _Malformed

__all__ = ["ParseOutput"]


class ParseOutput:
    """Events and open elements of one parse (``strict``: the parser's mode)."""

    def __init__(self, strict: bool) -> None:
        self.strict = strict
        #: open elements, outermost first: (name, where its start-tag was)
        self.stack: list[tuple[str, Position]] = []
        #: the events of the current feed/close call
        self.events: list[Event] = []
        #: text pieces not yet emitted, and where the first of them began
        self.tparts: list[str] = []
        self.tpos = _NOPOS

    def text_at(self, s: str, pos: Position) -> None:
        """Speech ``s``; ``pos``: where it begins (used when it starts a new text event)."""
        if not self.tparts:
            self.tpos = pos
        self.tparts.append(s)

    def flush_text(self) -> None:
        """Emit the held text pieces as one :class:`Text` event."""
        parts = self.tparts
        if parts:
            self.events.append(Text(parts[0] if len(parts) == 1 else "".join(parts), self.tpos))
            self.tparts = []

    def warn(self, message: str, pos: Position) -> None:
        """A lenient recovery at ``pos``: a :class:`ParseWarning` event after the text before it."""
        self.flush_text()
        self.events.append(ParseWarning(message, pos))

    def start(self, name: str, attrs: dict[str, str], empty: bool, pos: Position, refused: str | None) -> None:
        """A complete start-tag (``empty``: an empty-element tag, which opens nothing)."""
        self.flush_text()
        if empty:
            self.events.append(EmptyTag(name, attrs, pos, refused))
        else:
            self.events.append(StartTag(name, attrs, pos, refused))
            self.stack.append((name, pos))

    def end(self, name: str, pos: Position) -> None:
        """A complete end-tag ``</name>`` at ``pos`` (see the module docstring for a mismatched one)."""
        stack = self.stack
        self.flush_text()
        if stack and stack[-1][0] == name:
            stack.pop()
            self.events.append(EndTag(name, pos))
            return
        if self.strict:
            if stack:
                top, tpos = stack[-1]
                msg = f"mismatched end-tag </{name}>: expected </{top}> (<{top}> opened at {tpos})"
            else:
                msg = f"end-tag </{name}> closes no open element"
            raise _Malformed(msg, pos=pos)
        names = [n for n, _ in stack]
        if name not in names:
            self.warn(f"end-tag </{name}> closes no open element; dropped", pos)
            return
        while stack[-1][0] != name:
            inner, _ = stack.pop()
            self.warn(f"end-tag </{name}> closes unclosed <{inner}>", pos)
            self.events.append(EndTag(inner, pos))
        stack.pop()
        self.events.append(EndTag(name, pos))

    def close_all(self, pos: Position) -> None:
        """End of stream, lenient: close every open element at ``pos`` (a warning and an :class:`EndTag` each)."""
        while self.stack:
            name, opened = self.stack.pop()
            self.warn(f"<{name}> (opened at {opened}) not closed; closed at end", pos)
            self.events.append(EndTag(name, pos))
