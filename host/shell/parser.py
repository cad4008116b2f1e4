"""Incremental, push-based parser for XML function tokens (the paper's Appendix A.1 / A.3).

The LLM stream is an XML 1.0 *fragment*: text (speech) mixed with start-tags, end-tags and
empty-element tags, references, comments and CDATA sections; several top-level elements are allowed.
``FunctionTokenParser.feed(chunk)`` returns the events completed by that chunk:

* a tag event is emitted the moment its closing ``>`` is fed;
* text is emitted as it arrives and held back only while a ``<`` or ``&`` sequence is incomplete
  (plus a trailing CR, which might be half of a CRLF, and a trailing ``]``/``]]``, which might start
  the forbidden ``]]>``);
* work is linear in the input: the parser is a state machine that never re-scans consumed input and
  holds at most the one incomplete token (bounded by ``MAX_TOKEN`` characters).

Why hand-written rather than ``xml.parsers.expat`` or ``xml.etree.XMLPullParser``: expat needs a single
root element and treats the fragment as a document, reports text only through callbacks with no way to
tell "incomplete so far" from "malformed", cannot recover from the errors real LLM output contains
(lenient mode) and raises on DTD/PI rules differently from the paper's schema. Expat is the reference
in the differential tests.

Strict mode (the paper's): a mismatched end-tag, malformed tag, bad reference, processing instruction,
DTD or an unclosed element at ``close()`` raises :class:`ParseError`; the parser is then dead and
every further ``feed``/``close`` raises too. Lenient mode recovers and reports each recovery with a
:class:`ParseWarning` event:

* a ``<`` or ``&`` that cannot start markup becomes text (``a < b``, ``I <3 you``, ``AT&T``, ``&foo;``);
* markup is never spoken: a malformed tag (``<`` followed by a name, ``/``, ``!`` or ``?``) that
  cannot be recovered is dropped up to its ``>`` (or up to the next ``<``, where scanning resumes),
  and a stray residue of it right after (``"/>``, ``/>``, ``>``) is dropped too;
* attributes not separated by whitespace (``<nod a="1"b="2"/>``) are recovered as separate
  attributes (unambiguous once the value's closing quote was seen);
* an end-tag that closes nothing is dropped; one naming an open ancestor first closes the inner
  elements (an ``EndTag`` for each);
* a processing instruction (``<?...?>``) or ``<!DOCTYPE ...>`` is skipped;
* a duplicate attribute marks the tag ``refused`` (the shell fails that call, in both modes: strict
  raises); an invalid XML character is dropped; ``]]>`` in text is kept as text;
* at ``close()``: unclosed elements get their ``EndTag``; an incomplete reference becomes text; an
  incomplete tag, comment or declaration (a truncated function token) is dropped.

Positions: ``line`` and ``column`` are 1-based, ``offset`` is 0-based and counts characters of the
stream *after* line-ending normalisation (CRLF and lone CR become LF, as XML requires).
"""

from __future__ import annotations

from typing import NoReturn

from host.shell.parse_events import _NOPOS, EmptyTag, EndTag, Event, ParseError, ParseWarning, Position, StartTag, Text
from host.shell.parse_lex import (
    _AFTER, _ANAME, _ATTR, _CDATA, _COMMENT, _DECL_PREFIXES, _DECL_SCAN, _EAFTER, _ENAME, _ENAME0, _EQ, _ETAG,
    _INVALID, _LT, _NAME_ST, _NAMECHARS, _NAMESTART, _PLAIN_TEXT, _PREQ, _REF, _REFCHARS, _RESIDUE,
    _RESIDUE_PREFIX, _SKIP_DECL, _SKIP_PI, _SKIP_TAG, _SKIP_TAG_END, _SLASH, _STAG, _TAG, _TEXT, _TEXT_SPECIAL,
    _UNQUOTED, _UVALUE, _VALUE, _VALUE_END, _WS, MAX_TOKEN,
)
from host.shell.parse_out import ParseOutput
from host.shell.parse_values import _attr_value, _char_ref, _Malformed, _ref_problem

__all__ = [
    "MAX_TOKEN",
    "EmptyTag",
    "EndTag",
    "Event",
    "FunctionTokenParser",
    "ParseError",
    "ParseWarning",
    "Position",
    "StartTag",
    "Text",
    "parse",
]


class FunctionTokenParser:
    """Streaming SAX-style parser for function-token fragments (see the module docstring).

    >>> p = FunctionTokenParser()
    >>> p.feed('Hi <face_emo emo="wi')
    [Text(text='Hi ', pos=Position(line=1, column=1, offset=0))]
    >>> [type(e).__name__ for e in p.feed('nk"/> there')]
    ['EmptyTag', 'Text']
    """

    def __init__(self, strict: bool = True) -> None:
        self.strict = strict
        #: events, merged text and the open elements
        self._out = ParseOutput(strict)
        self._mode = _TEXT
        self._carry = ""  # bounded lookahead (<= 9 chars) re-fed at the start of the next feed
        self._cr = False  # trailing CR held back (maybe half of a CRLF)
        self._off = 0  # stream offset of the next input character
        self._line = 1
        self._line_start = 0  # offset of the first character of the current line
        self._dead: ParseError | None = None
        self._closed = False
        # the one incomplete token
        self._ts = _LT
        self._tok_i = 0
        self._tok_off = 0
        self._tok_len = 0
        self._tok_pos = _NOPOS
        self._tok_raw: list[str] = []
        self._tok_line = (1, 0)
        self._tname: list[str] = []
        self._aname: list[str] = []
        self._vparts: list[str] = []
        self._quote = '"'
        self._had_space = False
        self._attrs: dict[str, str] = {}
        self._depth = 0
        self._refusal: str | None = None  # lenient: why the tag being parsed must not run
        self._residue = False  # lenient: a malformed tag was just dropped; drop its '"/>' residue
        # per-call working state
        self._buf = ""
        self._base = 0
        self._lc_i = 0

    # ------------------------------------------------------------------------------ public API
    @property
    def open_elements(self) -> tuple[str, ...]:
        """Names of the currently open elements, outermost first."""
        return tuple(name for name, _ in self._out.stack)

    @property
    def incomplete(self) -> bool:
        """True while input is held back as "incomplete so far" (never means malformed)."""
        return bool(self._carry) or self._cr or self._mode != _TEXT

    @property
    def pending_kind(self) -> str | None:
        """What is incomplete so far: ``"tag"``, ``"end-tag"``, ``"reference"``, ``"comment"``,
        ``"cdata"``, ``"markup"`` (a ``<`` or ``<!`` prefix), ``"text"`` (a held ``]`` or CR),
        ``"processing-instruction"``/``"declaration"`` (lenient skip), or None."""
        mode = self._mode
        if mode == _TAG:
            return "end-tag" if self._ts in (_ENAME0, _ENAME, _EAFTER) else "tag"
        if mode != _TEXT:
            return {
                _REF: "reference",
                _COMMENT: "comment",
                _CDATA: "cdata",
                _SKIP_PI: "processing-instruction",
                _SKIP_DECL: "declaration",
                _SKIP_TAG: "malformed-tag",
            }[mode]
        if self._carry.startswith("<"):
            return "markup"
        if self._carry or self._cr:
            return "text"
        return None

    @property
    def pending(self) -> str:
        """Raw text held back so far (the incomplete tag or reference; comment/CDATA bodies are
        streamed or discarded, not held)."""
        if self._mode in (_TAG, _REF):
            return "".join(self._tok_raw) + self._carry
        return self._carry + ("\r" if self._cr else "")

    def feed(self, text: str) -> list[Event]:
        """Parse the next chunk of the stream; return the events it completed."""
        if self._dead is not None or self._closed:
            self._check_alive()
        if (
            self._mode == _TEXT
            and not self._carry
            and not self._cr
            and not self._residue
            and text
            and _PLAIN_TEXT.fullmatch(text) is not None
        ):
            # hot path: a chunk of plain speech while no token is pending
            off = self._off
            ev: list[Event] = [Text(text, Position(self._line, off - self._line_start + 1, off))]
            k = text.count("\n")
            if k:
                self._line += k
                self._line_start = off + text.rfind("\n") + 1
            self._off = off + len(text)
            return ev
        if self._cr:
            text = "\r" + text
            self._cr = False
        if text[-1:] == "\r":
            text = text[:-1]
            self._cr = True
        if "\r" in text:
            text = text.replace("\r\n", "\n").replace("\r", "\n")
        return self._run(text, False)

    def close(self) -> list[Event]:
        """End of stream: flush held text and check everything is closed; return the last events."""
        self._check_alive()
        tail = "\n" if self._cr else ""
        self._cr = False
        try:
            return self._run(tail, True)
        finally:
            self._closed = True

    # ------------------------------------------------------------------------------ driver
    def _check_alive(self) -> None:
        if self._dead is not None:
            d = self._dead
            raise ParseError(
                f"parser stopped after an earlier error: {d.message}", d.line, d.column, d.offset
            )
        if self._closed:
            raise ParseError("parser already closed", self._line, 1, self._off)

    def _run(self, text: str, final: bool) -> list[Event]:
        carry = self._carry
        if carry:
            self._base = self._off - len(carry)
            text = carry + text
            self._carry = ""
        else:
            self._base = self._off
        self._buf = text
        self._lc_i = 0
        events: list[Event] = []
        self._out.events = events
        try:
            self._scan()
            if final:
                self._finish()
        except _Malformed as exc:  # strict mode only
            self._die(exc)
        if self._out.tparts:
            self._out.flush_text()
        # line accounting up to the carry (which is re-fed next time); the buffer may have been
        # rebuilt by a lenient recovery, so read it back
        buf = self._buf
        end = len(buf) - len(self._carry)
        lc = self._lc_i
        if end > lc:
            k = buf.count("\n", lc, end)
            if k:
                self._line += k
                self._line_start = self._base + buf.rfind("\n", lc, end) + 1
            self._lc_i = end
        self._off = self._base + len(buf)
        return events

    def _die(self, exc: _Malformed) -> NoReturn:
        pos = exc.pos if exc.pos is not None else self._pos_of(exc.index)
        self._out.flush_text()
        err = ParseError(
            exc.message,
            pos.line,
            pos.column,
            pos.offset,
            incomplete=exc.incomplete,
            events=self._out.events,
        )
        self._dead = err
        raise err from None

    # ------------------------------------------------------------------------------ positions
    def _pos(self, i: int) -> Position:
        """Position of buffer index ``i`` (monotonic within a call); advances line tracking."""
        lc = self._lc_i
        if i > lc:
            buf = self._buf
            k = buf.count("\n", lc, i)
            if k:
                self._line += k
                self._line_start = self._base + buf.rfind("\n", lc, i) + 1
            self._lc_i = i
        off = self._base + i
        return Position(self._line, off - self._line_start + 1, off)

    def _pos_of(self, i: int) -> Position:
        """Position of index ``i`` without the monotonic requirement (error reports only)."""
        if i >= self._lc_i:
            return self._pos(i)
        buf = self._buf
        line = self._line - buf.count("\n", i, self._lc_i)
        nl = buf.rfind("\n", 0, i)
        start = self._base + nl + 1 if nl >= 0 else self._line_start
        off = self._base + i
        return Position(line, off - start + 1, off)

    # ------------------------------------------------------------------------------ emitters
    def _text(self, s: str, i: int) -> None:
        out = self._out
        if not out.tparts:
            out.tpos = self._pos(i)
        out.tparts.append(s)

    def _checked_text(self, seg: str, i: int) -> None:
        """Emit ``seg`` (buffer index ``i``) after rejecting/dropping non-XML characters."""
        m = _INVALID.search(seg)
        while m is not None:
            j = m.start()
            msg = f"character U+{ord(seg[j]):04X} is not allowed in XML"
            if self.strict:
                raise _Malformed(msg, i + j)
            if j:
                self._text(seg[:j], i)
            self._out.warn(msg + "; dropped", self._pos(i + j))
            seg = seg[j + 1 :]
            i += j + 1
            m = _INVALID.search(seg)
        if seg:
            self._text(seg, i)

    # ------------------------------------------------------------------------------ tokens
    def _begin(self, i: int, mode: int) -> None:
        """Start an incomplete token at buffer index ``i``."""
        self._tok_pos = self._pos(i)
        self._tok_line = (self._line, self._line_start)
        self._tok_off = self._base + i
        self._tok_i = i
        self._tok_raw = []
        self._tok_len = 0
        self._mode = mode
        self._ts = _LT
        self._tname = []
        self._attrs = {}
        self._refusal = None

    def _done_token(self) -> None:
        self._mode = _TEXT
        self._tok_raw = []

    def _bad_token(self, message: str, i: int, as_text: bool = False) -> tuple[str, int, int]:
        """Malformed tag or reference at buffer index ``i``.

        Strict: raise. Lenient, a tag-like token (``<`` + name, ``/``, ``!``): warn and drop it,
        skipping from ``i`` to its ``>`` or to the next ``<`` (:data:`_SKIP_TAG`). Lenient, a
        reference or a ``<`` that cannot start markup (``as_text``): warn, emit the opening
        ``<``/``&`` as text and resume scanning just after it (each character is re-scanned at most
        once, so work stays linear). Returns the (possibly rebuilt) buffer, its length and the
        position to resume at.
        """
        if self.strict:
            raise _Malformed(message, i)
        pos = self._tok_pos
        if self._mode == _TAG and not as_text:  # a tag-like token: drop it, never speak it
            self._out.warn(f"{message}; malformed tag dropped", pos)
            self._tok_raw = []
            self._refusal = None
            self._mode = _SKIP_TAG
            return self._buf, len(self._buf), i
        opener = "&" if self._mode == _REF else "<"
        self._out.warn(f"{message}; '{opener}' treated as text", pos)
        self._out.text_at(opener, pos)
        self._mode = _TEXT
        if not self._tok_raw:
            buf = self._buf
            return buf, len(buf), self._tok_i + 1
        # the token began in an earlier feed: re-scan its raw text (bounded by MAX_TOKEN) + buffer
        raw = "".join(self._tok_raw)[1:]
        self._tok_raw = []
        buf = raw + self._buf
        self._buf = buf
        self._base = self._tok_off + 1
        self._line, self._line_start = self._tok_line
        self._lc_i = 0
        return buf, len(buf), 0

    def _too_long(self, length: int) -> None:
        msg = f"tag or reference longer than {MAX_TOKEN} characters"
        if self.strict:
            raise _Malformed(msg, pos=self._tok_pos)
        self._out.warn(msg + "; dropped", self._tok_pos)
        self._done_token()

    # ------------------------------------------------------------------------------ the scanner
    def _scan(self) -> None:  # noqa: C901 - one state machine, kept together for speed
        buf = self._buf
        n = len(buf)
        pos = 0
        strict = self.strict
        if self._mode in (_TAG, _REF):
            self._tok_i = 0
        while pos < n:
            mode = self._mode
            if mode == _TEXT:
                if self._residue:
                    rm = _RESIDUE.match(buf, pos)
                    if rm is not None:
                        self._out.warn(f"residue {buf[pos:rm.end()].strip()!r} of a dropped tag; dropped", self._pos(pos))
                        pos = rm.end()
                        self._residue = False
                        continue
                    pm = _RESIDUE_PREFIX.match(buf, pos)
                    if pm is not None and pm.end() == n and n - pos <= 8 and pm.end() > pos:
                        self._carry = buf[pos:]  # maybe the start of a residue: decide with more input
                        return
                    if buf[pos] != "<":
                        self._residue = False
                m = _TEXT_SPECIAL.search(buf, pos)
                end = m.start() if m is not None else n
                if end > pos:
                    seg = buf[pos:end]
                    if "]]>" in seg:
                        j = seg.index("]]>")
                        if strict:
                            raise _Malformed("']]>' is not allowed in text", pos + j)
                        if j:
                            self._text(seg[:j], pos)
                        self._out.warn("']]>' in text; kept as text", self._pos(pos + j))
                        self._text(seg[j:], pos + j)
                    elif m is None and seg[-1] == "]":
                        k = 2 if seg.endswith("]]") else 1
                        if len(seg) > k:
                            self._text(seg[:-k], pos)
                        self._carry = seg[-k:]
                        return
                    else:
                        self._text(seg, pos)
                if m is None:
                    return
                c = buf[end]
                if c == "<":
                    if end + 1 >= n:
                        self._carry = "<"
                        return
                    if buf[end + 1] == "/":
                        mt = _ETAG.match(buf, end)
                        if mt is not None:
                            self._out.end(mt.group(1), self._pos(end))
                            pos = mt.end()
                            continue
                    else:
                        mt = _STAG.match(buf, end)
                        if mt is not None and mt.end() - end <= MAX_TOKEN:
                            tpos = self._pos(end)
                            attrs: dict[str, str] = {}
                            a_s = mt.group(2)
                            if a_s:
                                for am in _ATTR.finditer(a_s):
                                    an = am.group(1)
                                    v = am.group(2)
                                    if v is None:
                                        v = am.group(3)
                                    if "&" in v or "\t" in v or "\n" in v or _INVALID.search(v):
                                        v = _attr_value(v, tpos, strict, self._out.warn)
                                    if an in attrs:
                                        self._dup_attr(an, tpos)
                                    else:
                                        attrs[an] = v
                            refused, self._refusal = self._refusal, None
                            self._out.start(mt.group(1), attrs, mt.group(3) == "/", tpos, refused)
                            pos = mt.end()
                            continue
                    self._begin(end, _TAG)
                    pos = end + 1
                elif c == "&":
                    self._begin(end, _REF)
                    pos = end + 1
                else:
                    msg = f"character U+{ord(c):04X} is not allowed in XML"
                    if strict:
                        raise _Malformed(msg, end)
                    self._out.warn(msg + "; dropped", self._pos(end))
                    pos = end + 1
            elif mode == _TAG:
                ts = self._ts
                if ts == _NAME_ST or ts == _ANAME or ts == _ENAME:
                    m = _NAMECHARS.match(buf, pos)
                    assert m is not None  # a starred pattern always matches
                    e = m.end()
                    (self._aname if ts == _ANAME else self._tname).append(buf[pos:e])
                    pos = e
                    if e < n:
                        if ts == _NAME_ST:
                            self._ts = _AFTER
                            self._had_space = False
                        elif ts == _ANAME:
                            self._ts = _EQ
                        else:
                            self._ts = _EAFTER
                elif ts == _AFTER:
                    m = _WS.match(buf, pos)
                    assert m is not None  # a starred pattern always matches
                    e = m.end()
                    if e > pos:
                        self._had_space = True
                        pos = e
                        if e == n:
                            break
                    c = buf[e]
                    if c == ">":
                        pos = e + 1
                        if self._finish_stag(False, e):
                            continue
                    elif c == "/":
                        self._ts = _SLASH
                        pos = e + 1
                    elif _NAMESTART.match(c) and (self._had_space or not strict):
                        if not self._had_space:  # '<nod a="1"b="2"/>': unambiguous after the quote
                            self._out.warn(f"attributes of <{''.join(self._tname)}> must be separated by "
                                       "whitespace; recovered", self._pos(e))
                        self._aname = []
                        self._ts = _ANAME
                    else:
                        name = "".join(self._tname)
                        if _NAMESTART.match(c):
                            msg = f"attributes of <{name}> must be separated by whitespace"
                        elif c == "<":
                            msg = f"'<' inside tag <{name}> (tag not closed with '>')"
                        else:
                            msg = f"unexpected {c!r} in tag <{name}>"
                        buf, n, pos = self._bad_token(msg, e)
                elif ts == _UVALUE:
                    m = _UNQUOTED.match(buf, pos)
                    assert m is not None  # a starred pattern always matches
                    e = m.end()
                    self._vparts.append(buf[pos:e])
                    pos = e
                    if e < n:
                        self._end_attr()
                elif ts == _VALUE:
                    m = _VALUE_END[self._quote].search(buf, pos)
                    if m is None:
                        self._vparts.append(buf[pos:])
                        pos = n
                    else:
                        e = m.start()
                        self._vparts.append(buf[pos:e])
                        if buf[e] == "<":
                            buf, n, pos = self._bad_token(
                                "'<' is not allowed in an attribute value", e
                            )
                        else:
                            pos = e + 1
                            self._end_attr()
                elif ts == _EQ or ts == _PREQ:
                    m = _WS.match(buf, pos)
                    assert m is not None  # a starred pattern always matches
                    e = m.end()
                    pos = e
                    if e == n:
                        break
                    c = buf[e]
                    if ts == _EQ and c == "=":
                        self._ts = _PREQ
                        pos = e + 1
                    elif ts == _PREQ and (c == '"' or c == "'"):
                        self._quote = c
                        self._vparts = []
                        self._ts = _VALUE
                        pos = e + 1
                    elif ts == _PREQ and not strict and _UNQUOTED.match(buf, e).end() > e:  # type: ignore[union-attr]
                        self._out.warn(f"value of attribute '{''.join(self._aname)}' is not quoted; recovered",
                                   self._pos(e))
                        self._vparts = []
                        self._ts = _UVALUE
                    else:
                        an = "".join(self._aname)
                        what = "'='" if ts == _EQ else "a quoted value"
                        buf, n, pos = self._bad_token(
                            f"expected {what} after attribute name '{an}', got {c!r}", e
                        )
                elif ts == _LT:
                    c = buf[pos]
                    if c == "/":
                        self._ts = _ENAME0
                        pos += 1
                    elif _NAMESTART.match(c):
                        self._ts = _NAME_ST
                    elif c == "!":
                        head = buf[pos - 1 : pos + 8]
                        if head.startswith("<!--"):
                            self._mode = _COMMENT
                            pos = pos + 3
                        elif head.startswith("<![CDATA["):
                            self._out.flush_text()
                            self._mode = _CDATA
                            pos = pos + 8
                        elif head.startswith("<!DOCTYPE"):
                            msg = "a DTD (<!DOCTYPE ...>) is not allowed in function tokens"
                            if strict:
                                raise _Malformed(msg, pos - 1)
                            self._out.warn(msg + "; skipped", self._tok_pos)
                            self._mode = _SKIP_DECL
                            self._depth = 0
                            pos = pos + 8
                        elif pos - 1 + len(head) == n and any(
                            p.startswith(head) for p in _DECL_PREFIXES
                        ):
                            self._mode = _TEXT
                            self._carry = head
                            return
                        else:
                            buf, n, pos = self._bad_token(
                                "'<!' must start a comment '<!--' or a CDATA section '<![CDATA['",
                                pos,
                            )
                    elif c == "?":
                        msg = "processing instructions (<?...?>) are not allowed in function tokens"
                        if strict:
                            raise _Malformed(msg, pos - 1)
                        self._out.warn(msg + "; skipped", self._tok_pos)
                        self._mode = _SKIP_PI
                        pos += 1
                    else:
                        buf, n, pos = self._bad_token(
                            f"'<' must be followed by a name, '/', '!--' or '![CDATA[', got {c!r}",
                            pos,
                            as_text=True,
                        )
                elif ts == _SLASH:
                    if buf[pos] == ">":
                        pos += 1
                        if self._finish_stag(True, pos - 1):
                            continue
                    else:
                        buf, n, pos = self._bad_token(
                            f"expected '>' after '/' in tag <{''.join(self._tname)}>", pos
                        )
                elif ts == _ENAME0:
                    if _NAMESTART.match(buf[pos]):
                        self._ts = _ENAME
                    else:
                        buf, n, pos = self._bad_token(
                            f"'</' must be followed by a name, got {buf[pos]!r}", pos
                        )
                else:  # _EAFTER
                    m = _WS.match(buf, pos)
                    assert m is not None  # a starred pattern always matches
                    e = m.end()
                    pos = e
                    if e == n:
                        break
                    name = "".join(self._tname)
                    if buf[e] == ">":
                        pos = e + 1
                        length = self._base + pos - self._tok_off
                        if length > MAX_TOKEN:
                            self._too_long(length)
                            continue
                        self._done_token()
                        self._out.end(name, self._tok_pos)
                    else:
                        buf, n, pos = self._bad_token(
                            f"unexpected {buf[e]!r} in end-tag </{name}>", e
                        )
            elif mode == _REF:
                m = _REFCHARS.match(buf, pos)
                assert m is not None  # a starred pattern always matches
                e = m.end()
                self._tname.append(buf[pos:e])
                pos = e
                if e < n:
                    if buf[e] == ";":
                        body = "".join(self._tname)
                        s = _char_ref(body)
                        if s is None:
                            buf, n, pos = self._bad_token(_ref_problem(body), self._tok_i)
                        else:
                            pos = e + 1
                            self._done_token()
                            self._out.text_at(s, self._tok_pos)
                    else:
                        buf, n, pos = self._bad_token(
                            "'&' must start a reference like &amp; or &#38;", e
                        )
            elif mode == _CDATA:
                i = buf.find("]]>", pos)
                if i >= 0:
                    if i > pos:
                        self._checked_text(buf[pos:i], pos)
                    self._mode = _TEXT
                    pos = i + 3
                else:
                    k = 2 if buf.endswith("]]") else 1 if buf.endswith("]") else 0
                    if n - k > pos:
                        self._checked_text(buf[pos : n - k], pos)
                    self._carry = buf[n - k :] if k else ""
                    return
            elif mode == _COMMENT:
                i = buf.find("-", pos)
                stop = n if i < 0 else i
                if stop > pos:
                    bad = _INVALID.search(buf, pos, stop)
                    if bad is not None:
                        msg = f"character U+{ord(bad.group()):04X} is not allowed in XML"
                        if strict:
                            raise _Malformed(msg, bad.start())
                        self._out.warn(msg + "; ignored", self._pos(bad.start()))
                if i < 0:
                    return
                if i + 1 >= n:
                    self._carry = "-"
                    return
                if buf[i + 1] != "-":
                    pos = i + 1
                    continue
                if i + 2 >= n:
                    self._carry = "--"
                    return
                if buf[i + 2] == ">":
                    self._mode = _TEXT
                    pos = i + 3
                else:
                    if strict:
                        raise _Malformed("'--' is not allowed inside a comment", i)
                    self._out.warn("'--' inside a comment; ignored", self._pos(i))
                    pos = i + 2
            elif mode == _SKIP_TAG:
                m = _SKIP_TAG_END.search(buf, pos)
                if m is None:
                    return
                self._mode = _TEXT
                self._residue = True
                pos = m.end() if m.group() == ">" else m.start()
            elif mode == _SKIP_PI:
                i = buf.find("?>", pos)
                if i >= 0:
                    self._mode = _TEXT
                    pos = i + 2
                else:
                    if buf.endswith("?"):
                        self._carry = "?"
                    return
            else:  # _SKIP_DECL
                m = _DECL_SCAN.search(buf, pos)
                if m is None:
                    return
                pos = m.end()
                c = m.group()
                if c == "[":
                    self._depth += 1
                elif c == "]":
                    self._depth = max(0, self._depth - 1)
                elif self._depth == 0:
                    self._mode = _TEXT
        # end of buffer inside a tag or reference: keep its raw text (bounded) for recovery
        if self._mode in (_TAG, _REF):
            piece = buf[self._tok_i :]
            self._tok_raw.append(piece)
            self._tok_len += len(piece)
            if self._tok_len > MAX_TOKEN:
                self._too_long(self._tok_len)

    def _end_attr(self) -> None:
        """An attribute value is complete: store it (a repeated name refuses the tag) and expect whitespace."""
        an = "".join(self._aname)
        v = _attr_value("".join(self._vparts), self._tok_pos, self.strict, self._out.warn)
        if an in self._attrs:
            self._dup_attr(an, self._tok_pos)
        else:
            self._attrs[an] = v
        self._ts = _AFTER
        self._had_space = False

    def _dup_attr(self, name: str, pos: Position) -> None:
        msg = f"duplicate attribute '{name}'"
        if self.strict:
            raise _Malformed(msg, pos=pos)
        self._out.warn(msg + "; the call is refused", pos)
        self._refusal = f"{msg} (which value was meant is ambiguous)"

    def _finish_stag(self, empty: bool, gt: int) -> bool:
        """Complete the pending start/empty tag whose '>' is at buffer index ``gt``."""
        length = self._base + gt + 1 - self._tok_off
        if length > MAX_TOKEN:
            self._too_long(length)
            return True
        self._done_token()
        refused, self._refusal = self._refusal, None
        self._out.start("".join(self._tname), self._attrs, empty, self._tok_pos, refused)
        return True

    def _finish(self) -> None:
        """End of stream: resolve held lookahead, incomplete tokens and open elements."""
        strict = self.strict
        carry = self._carry
        self._carry = ""
        i = len(self._buf) - len(carry)
        mode = self._mode
        if carry and carry[0] == "]":
            self._text(carry, i)  # ']' / ']]' at the end of text or CDATA content
        elif carry and mode == _TEXT:  # '<', '<!', '<!-', ... an unfinished markup start
            msg = f"stream ended inside markup {carry!r}"
            if strict:
                raise _Malformed(msg, i, incomplete=True)
            self._out.warn(msg + "; dropped", self._pos(i))
        if mode == _TAG:
            what = "end-tag" if self._ts in (_ENAME0, _ENAME, _EAFTER) else "tag"
            msg = f"stream ended inside {what} {''.join(self._tok_raw)[:40]!r}"
            if strict:
                raise _Malformed(msg, pos=self._tok_pos, incomplete=True)
            self._out.warn(msg + "; dropped", self._tok_pos)
            self._done_token()
        elif mode == _REF:
            raw = "".join(self._tok_raw)
            msg = f"stream ended inside reference {raw[:40]!r}"
            if strict:
                raise _Malformed(msg, pos=self._tok_pos, incomplete=True)
            self._out.warn(msg + "; kept as text", self._tok_pos)
            self._out.text_at(raw, self._tok_pos)
            self._done_token()
        elif mode != _TEXT:
            what = {
                _COMMENT: "comment",
                _CDATA: "CDATA section",
                _SKIP_PI: "processing instruction",
                _SKIP_DECL: "declaration",
                _SKIP_TAG: "dropped malformed tag",
            }[mode]
            msg = f"stream ended inside a {what}"
            if strict:
                raise _Malformed(msg, len(self._buf), incomplete=True)
            self._out.warn(msg, self._pos(len(self._buf)))
            self._mode = _TEXT
        if self._out.stack:
            pos = self._pos(len(self._buf))
            if strict:
                name, opened = self._out.stack[-1]
                raise _Malformed(
                    f"stream ended with <{name}> (opened at {opened}) still open",
                    pos=pos,
                    incomplete=True,
                )
            self._out.close_all(pos)


def parse(text: str, strict: bool = True) -> list[Event]:
    """Parse a complete fragment in one go (feed + close)."""
    p = FunctionTokenParser(strict=strict)
    return p.feed(text) + p.close()
