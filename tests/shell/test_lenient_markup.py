"""Lenient mode never speaks markup: recoverable tags are recovered, the rest dropped with a warning.

A corpus of malformed-tag shapes seen in real LLM output, run through the whole
shell (parser, scheduler, speech) in lenient mode, chunked every way; the
property: no text handed to speech contains tag-like markup (``<`` glued to a
name, ``/``, ``!`` or ``?``, or a ``/>`` residue), and nothing crashes.
A duplicated attribute refuses the call in both modes.
"""

from __future__ import annotations

import re

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from host.shell.parser import EmptyTag, FunctionTokenParser, ParseError, Text, parse

pytestmark = pytest.mark.anyio

TAG_LIKE = re.compile(r"<[/!?]?[^\W\d]|/>")
#: the parser alone guarantees no '<' glued to a name; the shell also drops '< x/>' and residues
PARSER_TAG_LIKE = re.compile(r"<[/!?]?[^\W\d]")

#: shapes of malformed tags (and the well-formed ones around them)
CORPUS = [
    'Okay.<head_act action="nod"duration="1"/>',  # no space between attributes
    '<wait><play_bgm name="x</play_bgm>"/></wait><head_act action="nod" duration="1"/>',  # '<' in a value
    '<head_act action="nod" action="shake"/>',  # duplicated attribute
    '<head_act action=nod/>Fine.',  # unquoted value
    '<head_act action="nod/>Hello there. <wave/>',  # missing closing quote
    '<head_act action="nod" Hello. <wave/>',  # missing '>'
    '<head_act action="nod"/ >ok',  # space inside '/>'
    '< head_act/>Hi.',  # space after '<'
    '<<wave/>',  # doubled '<'
    '<wave/>>Hello.',  # doubled '>'
    '</wave>Stray end.',  # end-tag closing nothing
    "<head_act action='nod\">Mixed quotes.</head_act>",
    '<head_act action="nod">Unclosed element.',
    '<face_emo emo="happy" duration=>Empty value.',
    '<face_emo emo="happy" =1/>Nameless.',
    '<face_emo emo="happy" duration="2"',  # truncated at the end
    '<3 I <3 you & AT&T &foo; a < b',  # '<' and '&' that cannot start markup stay text
    '```xml\n<wave/>\n```',
    '<wave times="2"></wave times>Bad end-tag.',
    '<!-- a comment --><wave/><?pi?><!DOCTYPE x>Declarations.',
    '<head_act action="nod"/><head_act action="nod" duration="1"/><wave/>Fine sentence.',
]


def spoken_and_calls(events: list) -> tuple[str, list[str]]:
    return "".join(e.text for e in events if isinstance(e, Text)), [e.name for e in events if isinstance(e, EmptyTag)]


def test_the_issue_cases_parse_as_intended() -> None:
    text, calls = spoken_and_calls(parse(CORPUS[0], strict=False))
    assert text == "Okay." and calls == ["head_act"]
    events = parse(CORPUS[1], strict=False)
    text, calls = spoken_and_calls(events)
    assert text == "" and calls == ["head_act"]
    assert any("malformed tag dropped" in getattr(e, "message", "") for e in events)
    (tag,) = [e for e in parse(CORPUS[2], strict=False) if isinstance(e, EmptyTag)]
    assert tag.refused is not None and "duplicate attribute 'action'" in tag.refused
    with pytest.raises(ParseError, match="duplicate attribute"):
        parse(CORPUS[2], strict=True)
    with pytest.raises(ParseError, match="separated by whitespace"):
        parse(CORPUS[0], strict=True)


@pytest.mark.parametrize("source", CORPUS)
def test_parser_text_never_holds_tag_like_markup_whatever_the_chunking(source: str) -> None:
    for step in (1, 2, 3, 7, len(source)):
        p = FunctionTokenParser(strict=False)
        events = []
        for i in range(0, len(source), step):
            events += p.feed(source[i:i + step])
        events += p.close()
        text, _ = spoken_and_calls(events)
        assert not PARSER_TAG_LIKE.search(text), (step, text)


async def _speech_of(coco, program: str, chunks: list[str] | None = None, strict: bool = False):
    shell, _ = coco(strict=strict)
    result = await shell.run_text(chunks or [program])
    said = [r.args["text"] for r in result.timeline if r.function == "speak" and r.start is not None]
    return result, said


@pytest.mark.parametrize("source", CORPUS)
async def test_speech_never_contains_markup(coco, source: str) -> None:
    result, said = await _speech_of(coco, source)
    for s in said:
        assert not TAG_LIKE.search(s), (source, said)


async def test_issue_cases_through_the_shell(coco) -> None:
    result, said = await _speech_of(coco, CORPUS[0])
    assert said == ["Okay."] and result.timeline.one("head_act").outcome == "done"
    assert any("recovered" in o.message for o in result.observations)
    result, said = await _speech_of(coco, CORPUS[1])
    assert said == [] and result.timeline.one("head_act").outcome == "done"
    assert any("malformed tag dropped" in o.message for o in result.observations)
    for strict in (False, True):  # a duplicated attribute refuses the call in both modes
        result, said = await _speech_of(coco, CORPUS[2], strict=strict)
        assert not [r for r in result.timeline if r.function == "head_act" and r.outcome == "done"]
    result, _ = await _speech_of(coco, CORPUS[2])
    assert "refused" in str(result.timeline.one("head_act").error)


FRAGMENTS = st.sampled_from([
    '<head_act action="nod"/>', '<wave/>', "Hello there. ", "Fine! ", '<face_emo emo="happy">', "</face_emo>",
    "<", ">", "/>", '"', "'", "=", " ", "<head_act", ' action="nod"', "action=nod", '"/>', "</", "<wait>",
    "</wait>", "&", "&amp;", "<3", "a < b", "<!--", "-->", "<?", "?>", "\n", "duration", '="1"', "é", "生",
])


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(parts=st.lists(FRAGMENTS, max_size=24), step=st.integers(1, 9))
def test_property_lenient_speech_never_contains_markup(parts: list[str], step: int) -> None:
    import anyio

    from host.testing.quadruped import SimulatedQuadruped, modules
    from host.shell.registry import Registry
    from host.shell.shell import Shell

    source = "".join(parts)
    chunks = [source[i:i + step] for i in range(0, len(source), step)] or [""]

    async def main() -> list[str]:
        shell = Shell(Registry(modules(SimulatedQuadruped())), strict=False, clock=lambda: 0.0)
        result = await shell.run_text(chunks)
        assert result.error is None
        return [r.args["text"] for r in result.timeline if r.function == "speak"]

    from trio.testing import MockClock

    said = anyio.run(main, backend="trio", backend_options={"clock": MockClock(autojump_threshold=0)})
    for s in said:
        assert not TAG_LIKE.search(s), (source, s)
