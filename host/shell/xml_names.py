"""XML 1.0 character classes as regular-expression fragments.

Names follow the XML 1.0 (Fifth Edition) ``Name`` production (productions [4], [4a], [5]); the
``Char`` production [2] decides which characters may appear at all. Expat (used as the reference in
the tests) implements the older Fourth Edition name tables, which differ only for some non-Latin
characters; the Fifth Edition is the current recommendation and what the paper cites.
"""

from __future__ import annotations

import re

#: NameStartChar, production [4] (without the enclosing brackets).
NAME_START_CHARS = (
    ":A-Z_a-z\u00c0-\u00d6\u00d8-\u00f6\u00f8-\u02ff\u0370-\u037d\u037f-\u1fff"
    "\u200c-\u200d\u2070-\u218f\u2c00-\u2fef\u3001-\ud7ff\uf900-\ufdcf\ufdf0-\ufffd"
    "\U00010000-\U000effff"
)
#: NameChar, production [4a].
NAME_CHARS = NAME_START_CHARS + r"\-.0-9\u00b7\u0300-\u036f\u203f-\u2040"
#: S, production [3], after line-ending normalisation (no CR left).
WHITESPACE = " \t\n"

NAME_RE = re.compile(f"[{NAME_START_CHARS}][{NAME_CHARS}]*")
#: Characters that are *not* XML Chars (production [2]); CR is absent after normalisation.
INVALID_CHAR_CLASS = "\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff"
INVALID_CHAR_RE = re.compile(f"[{INVALID_CHAR_CLASS}]")


def is_name(s: str) -> bool:
    """True when ``s`` matches the XML ``Name`` production."""
    return NAME_RE.fullmatch(s) is not None


def is_xml_char(cp: int) -> bool:
    """True when code point ``cp`` is an XML ``Char`` (production [2])."""
    return (
        cp in (0x9, 0xA, 0xD)
        or 0x20 <= cp <= 0xD7FF
        or 0xE000 <= cp <= 0xFFFD
        or 0x10000 <= cp <= 0x10FFFF
    )
