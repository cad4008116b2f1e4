"""References and attribute values for :class:`host.shell.parser.FunctionTokenParser`, and its internal error.

:func:`_char_ref` resolves a reference body (``#123``, ``#x7B``, a predefined entity name);
:func:`_attr_value` normalises an attribute value as XML does (tab and newline become spaces) and
resolves its references. Malformed input raises :class:`_Malformed` in strict mode; in lenient mode
the callers' ``warn(message, pos)`` reports the recovery (an invalid character is dropped, a bad
reference kept as text) and parsing goes on. Names keep their leading underscore: the parser's
internals, shared by its modules only.
"""

from __future__ import annotations

import re
from collections.abc import Callable

from host.shell.parse_events import Position
from host.shell.parse_lex import _INVALID, _PREDEFINED, _VALUE_REF, _WS_TO_SPACE
from host.shell.xml_names import is_xml_char

#: a lenient recovery's report: ``warn(message, pos)``
Warn = Callable[[str, Position], None]


class _Malformed(Exception):
    """Internal: malformed input at buffer index ``index`` (or at ``pos``)."""

    def __init__(self, message: str, index: int = -1, pos: Position | None = None,
                 incomplete: bool = False) -> None:
        super().__init__(message)
        self.message = message
        self.index = index
        self.pos = pos
        self.incomplete = incomplete


def _char_ref(body: str) -> str | None:
    """Resolve ``#123`` / ``#x7B`` / predefined entity name; None when invalid."""
    if body[:2] == "#x":
        digits, base = body[2:], 16
        ok = digits != "" and all(c in "0123456789abcdefABCDEF" for c in digits)
    elif body[:1] == "#":
        digits, base = body[1:], 10
        ok = digits.isascii() and digits.isdigit()
    else:
        return _PREDEFINED.get(body)
    if not ok:
        return None
    digits = digits.lstrip("0") or "0"
    if len(digits) > 8:
        return None
    cp = int(digits, base)
    return chr(cp) if is_xml_char(cp) else None


def _ref_problem(body: str) -> str:
    if body.startswith("#"):
        return f"invalid character reference '&{body};'"
    if not body:
        return "empty reference '&;'"
    return f"undefined entity '&{body};' (only &lt; &gt; &amp; &apos; &quot; are predefined)"


def _attr_value(raw: str, pos: Position, strict: bool, warn: Warn) -> str:
    """Normalise an attribute value (of the tag at ``pos``) as XML does and resolve its references."""
    if "\t" in raw or "\n" in raw:
        raw = raw.translate(_WS_TO_SPACE)
    m = _INVALID.search(raw)
    if m is not None:
        msg = f"character U+{ord(m.group()):04X} is not allowed in XML"
        if strict:
            raise _Malformed(msg, pos=pos)
        warn(msg + "; dropped", pos)
        raw = _INVALID.sub("", raw)
    if "&" in raw:
        raw = _VALUE_REF.sub(lambda mm: _value_ref(mm, pos, strict, warn), raw)
    return raw


def _value_ref(m: re.Match[str], pos: Position, strict: bool, warn: Warn) -> str:
    if m.group(1) is not None:
        body = "#" + m.group(1)
    elif m.group(2) is not None:
        body = "#x" + m.group(2)
    elif m.group(3) is not None:
        body = m.group(3)
    else:
        msg = "'&' in an attribute value must start a reference like &amp; or &#38;"
        if strict:
            raise _Malformed(msg, pos=pos)
        warn(msg + "; kept as text", pos)
        return "&"
    s = _char_ref(body)
    if s is None:
        msg = _ref_problem(body)
        if strict:
            raise _Malformed(msg, pos=pos)
        warn(msg + "; kept as text", pos)
        return m.group(0)
    return s
