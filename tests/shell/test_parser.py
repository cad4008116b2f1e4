"""Unit tests for the streaming function-token parser (host.shell.parser), one rule at a time."""

from __future__ import annotations

import pytest

from host.shell.parser import (
    MAX_TOKEN,
    EmptyTag,
    EndTag,
    Event,
    FunctionTokenParser,
    ParseError,
    ParseWarning,
    Position,
    StartTag,
    Text,
    parse,
)


def feed_all(chunks: list[str] | str, strict: bool = True) -> list[Event]:
    p = FunctionTokenParser(strict=strict)
    out: list[Event] = []
    for c in chunks:
        out += p.feed(c)
    return out + p.close()


def merged(events: list[Event]) -> list[Event]:
    out: list[Event] = []
    for e in events:
        if isinstance(e, Text) and out and isinstance(out[-1], Text):
            out[-1] = Text(out[-1].text + e.text, out[-1].pos)
        else:
            out.append(e)
    return out


def no_warnings(events: list[Event]) -> list[Event]:
    return [e for e in events if not isinstance(e, ParseWarning)]


def warnings(events: list[Event]) -> list[str]:
    return [e.message for e in events if isinstance(e, ParseWarning)]


# ------------------------------------------------------------------------------ events and API
def test_events_construct_without_position_and_compare_ignoring_it() -> None:
    assert StartTag("a", {}) == StartTag("a", {}, Position(3, 4, 20))
    assert Text("x").pos == Position(1, 1, 0)


def test_three_tag_kinds_text_and_positions() -> None:
    ev = parse('Hi <a x="1">in\n<b/></a>')
    assert ev == [Text("Hi "), StartTag("a", {"x": "1"}), Text("in\n"), EmptyTag("b", {}), EndTag("a")]
    assert [e.pos for e in ev] == [
        Position(1, 1, 0), Position(1, 4, 3), Position(1, 13, 12),
        Position(2, 1, 15), Position(2, 5, 19),
    ]


def test_open_elements_tracks_the_stack() -> None:
    p = FunctionTokenParser()
    p.feed("<a><b>")
    assert p.open_elements == ("a", "b")
    p.feed("</b>")
    assert p.open_elements == ("a",)


# ------------------------------------------------------------------------------ streaming
def test_tag_event_is_emitted_the_moment_its_gt_is_fed() -> None:
    p = FunctionTokenParser()
    s = '<face_emo emo="wink"/>'
    for c in s[:-1]:
        assert p.feed(c) == []
        assert p.incomplete and p.pending_kind in ("markup", "tag")  # "<" alone: markup
    assert p.feed(">") == [EmptyTag("face_emo", {"emo": "wink"})]
    assert not p.incomplete


def test_text_is_emitted_as_it_arrives_before_the_tag_completes() -> None:
    p = FunctionTokenParser()
    assert p.feed("Hello wor") == [Text("Hello wor")]
    assert p.feed("ld <nod tim") == [Text("ld ")]
    assert p.pending == "<nod tim"
    assert p.feed('es="2"/> ok') == [EmptyTag("nod", {"times": "2"}), Text(" ok")]


def test_text_is_held_only_while_a_reference_is_incomplete() -> None:
    p = FunctionTokenParser()
    assert p.feed("fish &am") == [Text("fish ")]
    assert p.pending_kind == "reference" and p.pending == "&am"
    assert p.feed("p; chips") == [Text("& chips")]


def test_trailing_bracket_and_cr_are_held_back() -> None:
    p = FunctionTokenParser()
    assert p.feed("a]") == [Text("a")]
    assert p.pending_kind == "text"
    assert p.feed("]b\r") == [Text("]]b")]
    assert p.feed("\nc") == [Text("\nc")]
    assert p.close() == []


def test_every_chunking_gives_the_same_merged_events() -> None:
    s = 'x <a k="v&amp;w"\r\n y=\'2\'>t&#x41;<![CDATA[<c>]]><!-- n --></a>\r\nz'
    ref = merged(parse(s))
    for k in range(1, 8):
        assert merged(feed_all([s[i : i + k] for i in range(0, len(s), k)])) == ref


# ------------------------------------------------------------------------------ grammar
def test_non_ascii_names_and_attribute_names() -> None:
    assert parse('<表情 情绪="开心"/><é-1.x:y/>') == [EmptyTag("表情", {"情绪": "开心"}), EmptyTag("é-1.x:y", {})]


@pytest.mark.parametrize("bad", ["<1a/>", "<-a/>", "<.a/>", "< a/>", "<a 1b='x'/>"])
def test_name_must_start_with_a_name_start_char(bad: str) -> None:
    with pytest.raises(ParseError):
        parse(bad)


def test_both_quote_kinds_and_whitespace_around_eq() -> None:
    ev = parse("<a x = 'it\"s'\n\ty\t=\"b'c\"   />")
    assert ev == [EmptyTag("a", {"x": 'it"s', "y": "b'c"})]


@pytest.mark.parametrize(
    "bad",
    ['<a x="1"y="2"/>', "<a x=1/>", '<a x"1"/>', '<a x="1/>', "<a/ >", '<a x="<"/>', "<a =\"1\"/>"],
)
def test_malformed_tags_are_rejected_in_strict_mode(bad: str) -> None:
    with pytest.raises(ParseError) as ei:
        parse(bad)
    assert ei.value.line == 1 and ei.value.offset >= 0


def test_duplicate_attribute_is_an_error() -> None:
    with pytest.raises(ParseError, match="duplicate attribute 'x'"):
        parse('<a x="1" x="2"/>')


def test_lt_not_allowed_in_attribute_value_but_gt_is() -> None:
    assert parse('<a x="a>b"/>') == [EmptyTag("a", {"x": "a>b"})]
    with pytest.raises(ParseError, match="'<' is not allowed in an attribute value"):
        feed_all(['<a x="a', "<b"])


def test_predefined_entities_and_character_references() -> None:
    ev = merged(parse('<a v="&lt;&gt;&amp;&apos;&quot;&#65;&#x42;&#x1F600;"/>&lt;&#x43;&#0068;'))
    assert ev == [EmptyTag("a", {"v": "<>&'\"AB\U0001F600"}), Text("<CD")]


@pytest.mark.parametrize(
    "bad", ["&foo;", "&#0;", "&#xD800;", "&#x110000;", "&#xFFFE;", "&#x;", "&#12a;", "&;", "a & b",
            '<a v="&#1;"/>', '<a v="&nope;"/>', '<a v="x & y"/>', "&#99999999999999999999;"],
)
def test_bad_references_are_rejected(bad: str) -> None:
    with pytest.raises(ParseError):
        parse(bad)


def test_attribute_value_normalisation_like_expat() -> None:
    # literal tab/newline/CR(LF) -> one space each; character references are kept as written
    ev = parse('<a v="x\ty\nz\r\nw\rq&#10;&#9;"/>')
    assert ev == [EmptyTag("a", {"v": "x y z w q\n\t"})]


def test_line_endings_are_normalised_across_chunk_boundaries() -> None:
    assert merged(feed_all(["a\r", "\nb\r", "c\r"])) == [Text("a\nb\nc\n")]
    ev = feed_all(["a\r", "\n<b/>"])
    assert ev[-1].pos == Position(2, 1, 2)


def test_comments_are_skipped_and_cdata_becomes_text() -> None:
    ev = merged(parse("a<!-- <x> & -- not -->b<![CDATA[<y> & ]] ]>]]>c".replace("-- not ", "not ")))
    assert ev == [Text("ab<y> & ]] ]>c")]


@pytest.mark.parametrize("bad", ["<!-- a -- b -->", "<!-- a --->", "<!- x ->", "<![CDATA[x", "<!-- x"])
def test_bad_comments_and_cdata(bad: str) -> None:
    with pytest.raises(ParseError):
        parse(bad)


def test_cdata_streams_its_content() -> None:
    p = FunctionTokenParser()
    assert p.feed("<![CDATA[hello <wo") == [Text("hello <wo")]
    assert p.feed("rld]") == [Text("rld")]
    assert p.pending_kind == "cdata"
    assert p.feed("]>x") == [Text("x")]


def test_cdata_end_in_text_is_an_error_even_split() -> None:
    with pytest.raises(ParseError, match=r"'\]\]>' is not allowed in text"):
        feed_all(["a]", "]", ">"])
    assert merged(parse("a]]b]>")) == [Text("a]]b]>")]


@pytest.mark.parametrize("bad", ['<?xml version="1.0"?><a/>', "x<?pi data?>", "<!DOCTYPE a><a/>"])
def test_dtd_and_processing_instructions_are_rejected(bad: str) -> None:
    with pytest.raises(ParseError, match="not allowed in function tokens"):
        parse(bad)


def test_invalid_xml_characters_are_rejected() -> None:
    with pytest.raises(ParseError, match="U\\+0001"):
        parse("a\x01b")


# ------------------------------------------------------------------------------ strict mode errors
def test_mismatched_end_tag_reports_position_and_stops_the_stream() -> None:
    p = FunctionTokenParser()
    p.feed("<a>\n  <b>")
    with pytest.raises(ParseError, match=r"mismatched end-tag </a>: expected </b>") as ei:
        p.feed("x</a>")
    err = ei.value
    assert (err.line, err.column, err.offset) == (2, 7, 10)
    assert err.events == [Text("x")]  # what the failing call parsed first is not lost
    assert not err.incomplete
    with pytest.raises(ParseError, match="earlier error"):
        p.feed("more")
    with pytest.raises(ParseError):
        p.close()


def test_end_tag_closing_nothing_is_an_error() -> None:
    with pytest.raises(ParseError, match="closes no open element"):
        parse("</a>")


def test_unclosed_element_at_close_is_incomplete_not_malformed() -> None:
    p = FunctionTokenParser()
    p.feed("<a>text")
    with pytest.raises(ParseError, match="still open") as ei:
        p.close()
    assert ei.value.incomplete


@pytest.mark.parametrize("tail", ["<", "<a", '<a x="1', "</a", "&am", "<!-", "<!-- x", "<![CDA"])
def test_incomplete_token_is_reported_as_incomplete(tail: str) -> None:
    p = FunctionTokenParser()
    p.feed("ok " + tail)
    assert p.incomplete
    with pytest.raises(ParseError) as ei:
        p.close()
    assert ei.value.incomplete


def test_malformed_is_detected_before_the_tag_ends() -> None:
    p = FunctionTokenParser()
    with pytest.raises(ParseError, match="expected '='"):
        p.feed("<a b c")


def test_feed_after_close_raises() -> None:
    p = FunctionTokenParser()
    p.close()
    with pytest.raises(ParseError, match="closed"):
        p.feed("x")


def test_token_size_is_bounded() -> None:
    p = FunctionTokenParser()
    p.feed('<a v="')
    with pytest.raises(ParseError, match="longer than"):
        for _ in range(MAX_TOKEN // 1000 + 2):
            p.feed("x" * 1000)
    with pytest.raises(ParseError, match="longer than"):
        parse('<a v="' + "x" * MAX_TOKEN + '"/>')


# ------------------------------------------------------------------------------ lenient mode
def test_lenient_lt_and_amp_that_cannot_start_markup_become_text() -> None:
    ev = feed_all(["if a < b ", "&& AT&T; x &foo; y", " <3"], strict=False)
    assert merged(no_warnings(ev)) == [Text("if a < b && AT&T; x &foo; y <3")]
    # "< ", "&&" (two), "&T;" (undefined), "&foo;", "<3"
    assert len(warnings(ev)) == 6


def test_lenient_malformed_tag_is_dropped_never_spoken_and_scanning_resumes() -> None:
    ev = feed_all(["say <b and c", "> then <nod/>"], strict=False)
    assert merged(no_warnings(ev)) == [Text("say  then "), EmptyTag("nod", {})]
    ev = feed_all(["x <a <b/>"], strict=False)
    assert merged(no_warnings(ev)) == [Text("x "), EmptyTag("b", {})]


def test_lenient_end_tag_closing_nothing_is_dropped() -> None:
    ev = feed_all("a</x>b", strict=False)
    assert merged(no_warnings(ev)) == [Text("ab")]
    assert warnings(ev) == ["end-tag </x> closes no open element; dropped"]


def test_lenient_end_tag_naming_an_ancestor_closes_inner_elements() -> None:
    ev = no_warnings(feed_all("<a><b><c>x</a>", strict=False))
    assert ev == [StartTag("a", {}), StartTag("b", {}), StartTag("c", {}), Text("x"),
                  EndTag("c"), EndTag("b"), EndTag("a")]


def test_lenient_unclosed_elements_are_closed_at_close() -> None:
    ev = feed_all("<a><b/>", strict=False)
    assert no_warnings(ev) == [StartTag("a", {}), EmptyTag("b", {}), EndTag("a")]
    assert len(warnings(ev)) == 1


def test_lenient_truncated_tag_is_dropped_but_reference_kept() -> None:
    assert merged(no_warnings(feed_all('ok <nod times="', strict=False))) == [Text("ok ")]
    assert merged(no_warnings(feed_all("AT&T", strict=False))) == [Text("AT&T")]


def test_lenient_skips_pi_and_doctype_and_keeps_first_duplicate() -> None:
    ev = feed_all(['<?xml version="1.0"?><!DOCTYPE a [<!ELEMENT a ANY>]>', '<a x="1" x="2"/>'],
                  strict=False)
    assert no_warnings(ev) == [EmptyTag("a", {"x": "1"})]
    assert len(warnings(ev)) == 3


def test_lenient_cdata_end_in_text_and_bad_chars() -> None:
    ev = feed_all("a]]>b\x00c", strict=False)
    assert merged(no_warnings(ev)) == [Text("a]]>bc")]


def test_lenient_recovery_of_a_tag_spanning_feeds_keeps_positions() -> None:
    ev = feed_all(["hi <b", " and\nc", "> <x/>"], strict=False)
    assert merged(no_warnings(ev)) == [Text("hi  "), EmptyTag("x", {})]  # the malformed tag is dropped
    assert [e for e in ev if isinstance(e, EmptyTag)][0].pos == Position(2, 4, 13)


def test_lenient_oversize_tag_is_dropped_without_unbounded_growth() -> None:
    p = FunctionTokenParser(strict=False)
    p.feed('<a v="')
    out: list[Event] = []
    for _ in range(MAX_TOKEN // 1000 + 2):
        out += p.feed("x" * 1000)
    assert any("longer than" in w for w in warnings(out))
    assert len(p.pending) <= MAX_TOKEN


# ------------------------------------------------------------------------------ linear work
def test_one_megabyte_fed_char_by_char_completes() -> None:
    unit = 'Hello &amp; welcome <nod times="2" speed="fast">ok</nod>\n'
    s = unit * (1_000_000 // len(unit))
    p = FunctionTokenParser()
    n = 0
    for c in s:
        n += len(p.feed(c))
    p.close()
    assert n > 4 * (len(s) // len(unit))


def test_a_long_pending_tag_fed_char_by_char_is_not_rescanned() -> None:
    # a 60 000-char attribute value fed one char at a time: quadratic re-scanning would take
    # ~1.8e9 character steps; the state machine does ~60 000
    p = FunctionTokenParser()
    p.feed('<a v="')
    for _ in range(60_000):
        p.feed("x")
    (ev,) = p.feed('"/>')
    assert isinstance(ev, EmptyTag) and len(ev.attrs["v"]) == 60_000
