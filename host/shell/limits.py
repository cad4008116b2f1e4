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
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Limits"]


@dataclass(frozen=True)
class Limits:
    """Limits for one turn; raise :class:`ValueError` from :meth:`validate` when one is not positive."""

    max_text_chars: int = 1_000_000
    max_calls: int = 5_000
    max_queued_per_channel: int = 1_000
    max_attr_chars: int = 4_096
    max_scope_timeout_s: float = 600.0  # seconds of the shell's clock (board time in real runs)

    def validate(self) -> Limits:
        for name in ("max_text_chars", "max_calls", "max_queued_per_channel", "max_attr_chars"):
            if getattr(self, name) < 1:
                raise ValueError(f"Limits.{name} must be at least 1, got {getattr(self, name)}")
        if not 0 < self.max_scope_timeout_s < float("inf"):
            raise ValueError(f"Limits.max_scope_timeout_s must be a finite number above 0, got {self.max_scope_timeout_s}")
        return self
