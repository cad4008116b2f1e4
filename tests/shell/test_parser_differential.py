"""Differential tests: the streaming parser against expat on the fragment wrapped in a root element.

For any generated well-formed fragment and any chunking of it, the events (adjacent text merged) equal
what expat reports; for near-miss mutations, strict mode accepts exactly what expat accepts.
"""

from __future__ import annotations

import xml.parsers.expat

from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from host.shell.parser import EmptyTag, EndTag, Event, FunctionTokenParser, ParseError, StartTag, Text

ROOT = "R0ot"

Norm = tuple  # ("start", name, attrs) | ("end", name) | ("text", str)


def expat_events(fragment: str) -> list[Norm] | None:
    """Events expat reports for ``<R0ot>fragment</R0ot>`` (None when expat rejects it)."""
    out: list[Norm] = []
    p = xml.parsers.expat.ParserCreate()
    p.StartElementHandler = lambda name, attrs: out.append(("start", name, dict(attrs)))
    p.EndElementHandler = lambda name: out.append(("end", name))
    p.CharacterDataHandler = lambda data: out.append(("text", data))
    try:
        p.Parse(f"<{ROOT}>{fragment}</{ROOT}>", True)
    except xml.parsers.expat.ExpatError:
        return None
    assert out[0] == ("start", ROOT, {}) and out[-1] == ("end", ROOT)
    return merge_text(out[1:-1])


def merge_text(events: list[Norm]) -> list[Norm]:
    """Merge adjacent text events and drop empty ones."""
    merged: list[Norm] = []
    for e in events:
        if e[0] == "text":
            if not e[1]:
                continue
            if merged and merged[-1][0] == "text":
                merged[-1] = ("text", merged[-1][1] + e[1])
                continue
        merged.append(e)
    return merged


def normalise(events: list[Event]) -> list[Norm]:
    """Our events in expat's vocabulary (an empty-element tag is a start plus an end)."""
    out: list[Norm] = []
    for e in events:
        if isinstance(e, StartTag):
            out.append(("start", e.name, dict(e.attrs)))
        elif isinstance(e, EmptyTag):
            out.append(("start", e.name, dict(e.attrs)))
            out.append(("end", e.name))
        elif isinstance(e, EndTag):
            out.append(("end", e.name))
        elif isinstance(e, Text):
            out.append(("text", e.text))
    return merge_text(out)


# ------------------------------------------------------------------------------ generators
# Name characters on which XML 1.0 4th edition (expat) and 5th edition (ours) agree.
NAME_START = "abcxyzABZ_:éüñα中文"
NAME_REST = NAME_START + "019-.·"
names = st.builds(
    lambda a, b: a + b,
    st.sampled_from(NAME_START),
    st.text(alphabet=NAME_REST, max_size=6),
).filter(lambda n: n != ROOT)

REFS = ["&amp;", "&lt;", "&gt;", "&quot;", "&apos;", "&#65;", "&#x41;", "&#x1F600;", "&#10;",
        "&#x9;", "&#13;", "&#0065;", "&#xe9;"]
TEXT_CHARS = "ab z.,!?:;'\"=/>]\t\n\r-é中😀"


def _no_cdata_end(t: str) -> str:
    """No ']]>' inside, and no trailing ']' that could form one with the next piece."""
    while "]]>" in t:
        t = t.replace("]]>", "]>")
    return t + ("a" if t.endswith("]") else "")


plain = st.text(alphabet=TEXT_CHARS, min_size=1, max_size=12).map(_no_cdata_end)
cdata = st.text(alphabet=TEXT_CHARS + "<&", max_size=10).map(
    lambda t: "<![CDATA[" + t.replace("]]>", "]] >") + "]]>"
)
comment = st.text(alphabet="ab -<&>é\n", max_size=10).map(
    lambda t: "<!--" + t.replace("--", "- ").rstrip("-") + "-->"
)
text_piece = st.one_of(plain, st.sampled_from(REFS), cdata, comment)


text = st.lists(text_piece, min_size=1, max_size=4).map("".join)
ws = st.sampled_from(["", " ", "  ", "\t", "\n", "\r\n", " \r "])
ws1 = st.sampled_from([" ", "\t", "\n", "\r\n", "  \n "])
attr_val_chars = "ab 1.5-_é中>/=\t\n\r"


@st.composite
def attr_value(draw: st.DrawFn) -> str:
    q = draw(st.sampled_from(['"', "'"]))
    other = "'" if q == '"' else '"'
    pieces = draw(st.lists(st.one_of(st.text(alphabet=attr_val_chars + other, max_size=6),
                                     st.sampled_from(REFS)), max_size=3))
    return q + "".join(pieces) + q


@st.composite
def start_body(draw: st.DrawFn) -> str:
    name = draw(names)
    anames = draw(st.lists(names, max_size=3, unique=True))
    parts = [name]
    for an in anames:
        parts.append(draw(ws1) + an + draw(ws) + "=" + draw(ws) + draw(attr_value()))
    return "".join(parts) + draw(ws)


def _element(children: st.SearchStrategy[str]) -> st.SearchStrategy[str]:
    @st.composite
    def el(draw: st.DrawFn) -> str:
        body = draw(start_body())
        if draw(st.booleans()):
            return "<" + body + "/>"
        inner = "".join(draw(st.lists(children, max_size=3)))
        return "<" + body + ">" + inner + "</" + _tag_name(body) + draw(ws) + ">"

    return el()


def _tag_name(body: str) -> str:
    end = len(body)
    for i, c in enumerate(body):
        if c in " \t\r\n":
            end = i
            break
    return body[:end]


node = st.recursive(text, lambda kids: _element(st.one_of(text, kids)), max_leaves=12)
fragments = st.lists(node, max_size=4).map("".join)


def chunked(s: str, cuts: list[int]) -> list[str]:
    idx = sorted({min(c, len(s)) for c in cuts})
    out, prev = [], 0
    for c in idx + [len(s)]:
        out.append(s[prev:c])
        prev = c
    return out


def run_ours(chunks: list[str], strict: bool = True) -> list[Event]:
    p = FunctionTokenParser(strict=strict)
    events: list[Event] = []
    for c in chunks:
        events += p.feed(c)
    events += p.close()
    return events


def ours_or_none(chunks: list[str]) -> list[Norm] | None:
    try:
        return normalise(run_ours(chunks))
    except ParseError:
        return None


SETTINGS = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# ------------------------------------------------------------------------------ tests
@SETTINGS
@given(frag=fragments, cuts=st.lists(st.integers(0, 400), max_size=12))
def test_well_formed_fragments_match_expat_under_any_chunking(frag: str, cuts: list[int]) -> None:
    ref = expat_events(frag)
    assert ref is not None, f"generator produced a malformed fragment: {frag!r}"
    assert ours_or_none(chunked(frag, cuts)) == ref
    # char-by-char too: the hardest chunking for the state machine
    assert ours_or_none(list(frag)) == ref


MUTATION_CHARS = list("<>&;\"'/=! -]?#x\r\n\t") + ["\x01", "]]>", "--", "<!--", "<![CDATA[", "&#0;",
                                                     "&#x110000;", "&foo;", "<!DOCTYPE a>"]


@st.composite
def near_miss(draw: st.DrawFn) -> str:
    frag = draw(fragments.filter(bool))
    for _ in range(draw(st.integers(1, 2))):
        i = draw(st.integers(0, len(frag)))
        op = draw(st.sampled_from(["insert", "delete", "replace"]))
        if op == "insert":
            frag = frag[:i] + draw(st.sampled_from(MUTATION_CHARS)) + frag[i:]
        elif op == "delete":
            frag = frag[:i] + frag[i + 1 :]
        else:
            frag = frag[:i] + draw(st.sampled_from(MUTATION_CHARS)) + frag[i + 1 :]
    return frag


@settings(max_examples=600, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(frag=near_miss(), cuts=st.lists(st.integers(0, 400), max_size=8))
def test_strict_mode_accepts_and_rejects_what_expat_does(frag: str, cuts: list[int]) -> None:
    # Processing instructions are legal XML content but the paper's schema rejects them.
    assume("<?" not in frag)
    ref = expat_events(frag)
    got = ours_or_none(chunked(frag, cuts))
    assert got == ref, f"fragment {frag!r}: expat {'accepts' if ref is not None else 'rejects'}"


@SETTINGS
@given(frag=near_miss(), cuts=st.lists(st.integers(0, 400), max_size=8))
def test_lenient_mode_never_raises_and_is_chunking_invariant(frag: str, cuts: list[int]) -> None:
    whole = normalise(run_ours([frag], strict=False))
    assert normalise(run_ours(chunked(frag, cuts), strict=False)) == whole
    # and lenient equals strict whenever strict accepts
    strict = ours_or_none([frag])
    if strict is not None:
        assert whole == strict
