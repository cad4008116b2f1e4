"""Approximate LLM tokenisation, used to replay a program as a model would stream it.

Real BPE vocabularies (tiktoken & co.) need downloaded merge tables and differ
per provider; replay only needs *plausible* token boundaries, so this is a small
hand-written pre-tokeniser in the spirit of GPT-2/cl100k's regex:

* a word with its leading space (``" action"``), identifier pieces led by an
  underscore (``"_act"``), numbers in groups of at most 3 digits;
* punctuation runs of at most 3 characters (``"<"``, ``'="'``, ``'"/>'``);
* whitespace runs (a run before a word leaves its last space to the word);
* words longer than :data:`MAX_WORD` are cut into :data:`PIECE`-character
  pieces, and CJK runs into :data:`CJK_PIECE`-character pieces.

English prose comes out at about 4 characters per token, XML markup at about 3.
``"".join(tokenize(s)) == s`` always holds.
"""

from __future__ import annotations

import re

#: longest word kept whole (without its leading space)
MAX_WORD = 10
#: piece length when cutting longer words
PIECE = 4
#: characters per token in CJK text (modern tokenisers: roughly 1-2)
CJK_PIECE = 2
#: longest punctuation run kept whole
MAX_PUNCT = 3

_CJK = "\u3040-\u30ff\u3400-\u4dbf\u4e00-\u9fff\uac00-\ud7af\uf900-\ufaff"
_TOKEN_RE = re.compile(
    rf"""
    '(?:s|t|re|ve|m|ll|d)\b          # English contractions
  | [{_CJK}]+                        # CJK run (cut later)
  | \ ?(?:(?![{_CJK}])[^\W\d_])+     # optional space + letters
  | _(?:(?![{_CJK}])[^\W\d_])+       # identifier piece led by "_"
  | \ ?\d{{1,3}}                     # numbers, 3 digits at most
  | \ ?(?:[^\s\w]|_)+                # punctuation run (cut later)
  | \s+(?!\S)                        # trailing whitespace
  | \s+                              # whitespace
  | .                                # anything else, never reached
    """,
    re.VERBOSE | re.DOTALL,
)
_CJK_RE = re.compile(rf"[{_CJK}]")


def _cut(piece: str, size: int) -> list[str]:
    out = [piece[i : i + size] for i in range(0, len(piece), size)]
    if len(out) > 1 and len(out[-1]) == 1 and not _CJK_RE.match(out[-1]):
        out[-2:] = [out[-2] + out[-1]]
    return out


def tokenize(text: str) -> list[str]:
    """Split ``text`` into token-sized, non-empty pieces that concatenate back to ``text``."""
    tokens: list[str] = []
    for m in _TOKEN_RE.finditer(text):
        tok = m.group()
        if _CJK_RE.match(tok):
            tokens.extend(_cut(tok, CJK_PIECE))
        elif tok[-1].isspace():
            tokens.append(tok)
        elif tok[-1].isalpha():
            lead = tok[0] if tok[0] in " _" else ""
            body = tok[len(lead) :]
            if len(body) <= MAX_WORD:
                tokens.append(tok)
            else:
                parts = _cut(body, PIECE)
                parts[0] = lead + parts[0]
                tokens.extend(parts)
        elif not tok[-1].isdigit():
            tokens.extend(_cut(tok, MAX_PUNCT))
        else:
            tokens.append(tok)
    return tokens
