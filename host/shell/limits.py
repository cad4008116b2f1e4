"""Per-turn limits on what one LLM output stream may make the shell do (hostile or runaway output).

Every limit ends in a clear observation for the LLM's next turn and never in an exception:

==========================  =========  ==========================================================
limit                       default    when exceeded
==========================  =========  ==========================================================
``max_text_chars``          1 000 000  the rest of the turn's text is not spoken (one error)
``max_calls``               5 000      further elements are refused (one error, then counted)
``max_queued_per_channel``  1 000      a call on a channel with that many pending calls fails
``max_attr_chars``          4 096      an element with a longer attribute value fails
``max_scope_timeout_s``     600        a ``<wait>``/``<async>`` with a longer ``timeout`` fails
``MAX_DEPTH`` (scheduler)   64         a deeper element fails; its children attach above
==========================  =========  ==========================================================

The parser already caps one incomplete tag or reference at ``MAX_TOKEN`` (64 KiB) characters.
Speech segments count towards ``max_queued_per_channel`` (on the speech channel) but not towards
``max_calls`` (text has its own limit).

A reply known in full before it runs (``run --xml-file``, ``chat --replies``, an MCP
``run_program``) is checked first with :meth:`TurnLimits.refuse_reply`: one that exceeds the text or
call limit is refused before any of it runs, instead of running (and speaking) for minutes up to
the point where the limit cuts it.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from host.shell.parser import Event

__all__ = ["TurnLimits"]

_CHECK_CHUNK = 64 * 1024  # characters parsed between two checks of the counts


@dataclass(frozen=True)
class TurnLimits:
    """TurnLimits for one turn; raise :class:`ValueError` from :meth:`validate` when one is not positive."""

    max_text_chars: int = 1_000_000
    max_calls: int = 5_000
    max_queued_per_channel: int = 1_000
    max_attr_chars: int = 4_096
    max_scope_timeout_s: float = 600.0  # seconds of the shell's clock (board time in real runs)

    def validate(self) -> TurnLimits:
        for name in ("max_text_chars", "max_calls", "max_queued_per_channel", "max_attr_chars"):
            if getattr(self, name) < 1:
                raise ValueError(f"TurnLimits.{name} must be at least 1, got {getattr(self, name)}")
        if not 0 < self.max_scope_timeout_s < float("inf"):
            raise ValueError(f"TurnLimits.max_scope_timeout_s must be a finite number above 0, got {self.max_scope_timeout_s}")
        return self

    def refuse_reply(self, text: str) -> str | None:
        """Why the complete reply ``text`` exceeds these limits (one line), or None when it does not.

        Counts as the shell does: characters of text outside the elements (``max_text_chars``) and
        elements (``max_calls``), with the lenient parser (a malformed reply is refused or not by
        its size, never by its syntax). Cheap for ordinary replies (the whole text within both
        bounds is not parsed) and stops parsing at the first bound exceeded (2 MB of prose is
        refused after parsing ~1 MB, well under a second).
        """
        if len(text) <= self.max_text_chars and text.count("<") <= self.max_calls:
            return None
        from host.shell.parser import EmptyTag, Event, FunctionTokenParser, StartTag, Text

        parser = FunctionTokenParser(strict=False)
        chars = calls = 0

        def batches() -> Iterator[list[Event]]:
            for i in range(0, len(text), _CHECK_CHUNK):
                yield parser.feed(text[i:i + _CHECK_CHUNK])
            yield parser.close()

        for events in batches():
            for ev in events:
                if isinstance(ev, Text):
                    chars += len(ev.text)
                elif isinstance(ev, (StartTag, EmptyTag)):
                    calls += 1
            if chars > self.max_text_chars:
                return (f"the reply has more than {self.max_text_chars:,} characters of text (the per-turn limit "
                        f"max_text_chars); it is {len(text):,} characters long in all")
            if calls > self.max_calls:
                return f"the reply has more than {self.max_calls:,} calls (the per-turn limit max_calls)"
        return None
