"""The lexical tables of :class:`host.shell.parser.FunctionTokenParser`: its regexes, scanner modes and tag sub-states.

XML 1.0 names (:mod:`host.shell.xml_names`), text runs, whitespace, references; the fast-path patterns
of a complete well-formed tag inside one buffer (``_STAG``, ``_ATTR``, ``_ETAG``); the lenient
recoveries' patterns (a dropped tag's residue, unquoted values). Names keep their leading underscore:
they are the parser's internals, shared by its modules only.
"""

from __future__ import annotations

import re

from host.shell.xml_names import INVALID_CHAR_CLASS, NAME_CHARS, NAME_START_CHARS

#: Largest single tag or reference (characters) the parser will hold while it is incomplete.
MAX_TOKEN = 64 * 1024

# ----------------------------------------------------------------------------------------- regexes
_NS = NAME_START_CHARS
_NC = NAME_CHARS
_NAME = f"[{_NS}][{_NC}]*"
_S = "[ \t\n]"
_PLAIN_TEXT = re.compile(f"[^<&\\]\r{INVALID_CHAR_CLASS}]+")
_TEXT_SPECIAL = re.compile(f"[<&{INVALID_CHAR_CLASS}]")
_NAMESTART = re.compile(f"[{_NS}]")
_NAMECHARS = re.compile(f"[{_NC}]*")
_WS = re.compile(f"{_S}*")
_REFCHARS = re.compile(f"[#{_NC}]*")
_VALUE_END = {'"': re.compile('[<"]'), "'": re.compile("[<']")}
_INVALID = re.compile(f"[{INVALID_CHAR_CLASS}]")
# Fast paths: a complete, well-formed tag inside one buffer.
_STAG = re.compile(
    f"<({_NAME})((?:{_S}+{_NAME}{_S}*={_S}*(?:\"[^<\"]*\"|'[^<']*'))*){_S}*(/?)>"
)
_ATTR = re.compile(f"{_S}+({_NAME}){_S}*={_S}*(?:\"([^<\"]*)\"|'([^<']*)')")
_ETAG = re.compile(f"</({_NAME}){_S}*>")
_VALUE_REF = re.compile(f"&(?:#([0-9]+);|#x([0-9a-fA-F]+);|({_NAME});)?")
_WS_TO_SPACE = str.maketrans("\t\n", "  ")
_PREDEFINED = {"lt": "<", "gt": ">", "amp": "&", "apos": "'", "quot": '"'}
_DECL_PREFIXES = ("<!--", "<![CDATA[", "<!DOCTYPE")

# --------------------------------------------------------------------------------------- modes
_TEXT, _TAG, _REF, _COMMENT, _CDATA, _SKIP_PI, _SKIP_DECL, _SKIP_TAG = range(8)
#: what ends the skipping of a dropped malformed tag (lenient): its '>' or the next '<'
_SKIP_TAG_END = re.compile("[<>]")
#: residue of a dropped tag right after it (lenient): '"/>', "'>", '/>', '>'
_RESIDUE = re.compile("[ \t]*[\"']?[ \t]*/?[ \t]*>")
_RESIDUE_PREFIX = re.compile("[ \t]*[\"']?[ \t]*/?[ \t]*")
# tag sub-states
(_LT, _NAME_ST, _AFTER, _ANAME, _EQ, _PREQ, _VALUE, _SLASH, _ENAME0, _ENAME, _EAFTER, _UVALUE) = range(12)
#: an unquoted attribute value (lenient recovery, as HTML reads ``a=1``)
_UNQUOTED = re.compile("[^ \t\n<>/\"'=`]*")


_DECL_SCAN = re.compile(r"[\[\]>]")
