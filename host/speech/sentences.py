"""Split streamed text into sentences so speech can start before the reply ends.

A sentence ends at a run of ``. ! ? …`` or CJK ``。！？`` (plus closing quotes
or brackets) that is followed by whitespace; after a CJK terminator (or an
ellipsis right after a CJK character) any following character will do. A
blank line also ends a sentence. A terminator at the very end of the buffer is
undecided until the next character arrives, so ``3.`` + ``5`` never splits, and
the result does not depend on how the text was chunked. Common abbreviations
(``Dr.``, ``e.g.``) do not end sentences. Text without a boundary is cut at the
last clause mark or space once it exceeds ``max_chars``, so the buffer stays bounded.
"""

from __future__ import annotations

import re

#: default longest piece handed to the speech engine
MAX_CHARS = 300

_CLOSERS = "\"'”’)]」』）》"
_CJK_TERMS = "。！？"
_BOUNDARY = re.compile(rf"(?P<term>[.!?…{_CJK_TERMS}]+[{re.escape(_CLOSERS)}]*)|(?P<para>\n[ \t\r]*\n)")
_CUT = re.compile(r"[\s,;:，、；：]")
_RUN_CHARS = frozenset(".!?…" + _CJK_TERMS + _CLOSERS)
_ABBREV = frozenset({"mr", "mrs", "ms", "dr", "prof", "sr", "jr", "st", "vs", "e.g", "i.e", "cf", "approx"})
_WORD_BEFORE = re.compile(r"([\w.]+)$")


def _is_cjk(ch: str) -> bool:
    return "\u3040" <= ch <= "\u30ff" or "\u3400" <= ch <= "\u9fff" or "\uac00" <= ch <= "\ud7af"


def _skip_space(buffer: str, i: int) -> int:
    while i < len(buffer) and buffer[i].isspace():
        i += 1
    return i


def _cut_at(buffer: str, start: int, max_chars: int) -> int:
    """Length of the next piece of an over-long segment (needs ``max_chars + 1`` chars).

    Prefer the last clause mark or space; never split a terminator run (unless
    the whole window is one, a degenerate case), so streaming stays chunk-independent.
    """
    fallback: int | None = None
    for length in range(max_chars, 0, -1):
        prev, nxt = buffer[start + length - 1], buffer[start + length]
        if prev in _RUN_CHARS and nxt in _RUN_CHARS:
            continue  # inside a terminator run
        if _CUT.match(prev):
            return length
        if fallback is None:
            fallback = length
    return max_chars if fallback is None else fallback


def _emit_cut(buffer: str, start: int, max_chars: int, out: list[str]) -> int:
    cut = _cut_at(buffer, start, max_chars)
    piece = buffer[start : start + cut].strip()
    if piece:
        out.append(piece)
    return _skip_space(buffer, start + cut)


def split_sentences(buffer: str, max_chars: int = MAX_CHARS, context: str = "") -> tuple[list[str], str]:
    """Return ``(complete_sentences, rest)``; feed ``rest`` + new text next time.

    Sentences are stripped and non-empty; ``rest`` has no leading whitespace and
    at most ``max_chars`` characters. ``context``: the part of the current sentence
    already returned by an over-long cut (see :class:`SentenceSplitter`): whether a
    terminator ends a sentence may depend on it (the word before ``.``, the
    character before ``…``), so it is read, never returned.
    """
    return _split(buffer, max_chars, context)[:2]


#: longest context kept for the lookbehind rules (abbreviations, a CJK character before an ellipsis)
CONTEXT_CHARS = 64


def _split(buffer: str, max_chars: int, context: str) -> tuple[list[str], str, str]:
    """:func:`split_sentences` plus the new context (the already-returned part of the open sentence)."""
    if max_chars < 1:
        raise ValueError(f"max_chars must be >= 1, got {max_chars}")
    out: list[str] = []
    buffer = context + buffer
    seg = 0  # where the open sentence began: lookbehind rules read from here, cuts do not move it
    start = _skip_space(buffer, len(context))

    def emit_until(end: int) -> None:
        """Emit buffer[start:end] as one sentence, cutting pieces over max_chars."""
        nonlocal start, seg
        while end - start > max_chars:
            start = _emit_cut(buffer, start, max_chars, out)
        piece = buffer[start:end].strip()
        if piece:
            out.append(piece)
        start = seg = _skip_space(buffer, end)

    pos = start
    while (m := _BOUNDARY.search(buffer, pos)) is not None:
        a, b = m.span()
        pos = b
        if a < start:
            continue
        if m.group("para") is None:
            if b == len(buffer):
                break  # undecided until the next character arrives
            run = m.group("term")
            nxt = buffer[b]
            cjk = any(c in _CJK_TERMS for c in run) or ("…" in run and a > seg and _is_cjk(buffer[a - 1]))
            if not (nxt.isspace() or cjk):
                continue
            if run == ".":
                w = _WORD_BEFORE.search(buffer, seg, a)
                if w and w.group(1).lower() in _ABBREV:
                    continue
        emit_until(b)
        pos = max(pos, start)
    while len(buffer) - start > max_chars:  # over-long unterminated tail
        start = _emit_cut(buffer, start, max_chars, out)
    return out, buffer[start:], buffer[seg:start][-CONTEXT_CHARS:]


class SentenceSplitter:
    """Incremental :func:`split_sentences`: ``feed`` chunks, ``flush`` at the end."""

    def __init__(self, max_chars: int = MAX_CHARS) -> None:
        self.max_chars = max_chars
        self._buf = ""
        self._context = ""  # the open sentence's part already returned by over-long cuts

    @property
    def pending(self) -> str:
        """Text received but not yet returned as a sentence."""
        return self._buf

    def feed(self, text: str) -> list[str]:
        """Add ``text``; return the sentences it completed."""
        sentences, self._buf, self._context = _split(self._buf + text, self.max_chars, self._context)
        return sentences

    def flush(self) -> list[str]:
        """End of stream: return the pending text as a last sentence (if any)."""
        sentences, rest, _ = _split(self._buf, self.max_chars, self._context)
        self._buf, self._context = "", ""
        rest = rest.strip()
        return [*sentences, rest] if rest else sentences
