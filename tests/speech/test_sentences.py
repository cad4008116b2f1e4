"""Sentence splitting for streamed speech."""

from __future__ import annotations

import re

import hypothesis.strategies as st
import pytest
from hypothesis import assume, given, settings

from host.speech import SentenceSplitter, split_sentences


@pytest.mark.parametrize(
    ("buffer", "sentences", "rest"),
    [
        ("Hello there. How are you? Fine", ["Hello there.", "How are you?"], "Fine"),
        ("It is 3.5 metres. Ok", ["It is 3.5 metres."], "Ok"),
        ("Pi is 3.", [], "Pi is 3."),  # undecided: "3." may become "3.5"
        ("Really?! Yes! ", ["Really?!", "Yes!"], ""),
        ("Wait… what", ["Wait…"], "what"),
        ("你好。我是CoCo！你呢？好", ["你好。", "我是CoCo！", "你呢？"], "好"),
        ("好的……我们走吧", ["好的……"], "我们走吧"),
        ("他说：「好。」然后", ["他说：「好。」"], "然后"),
        ("Dr. Smith says hi. e.g. this one", ["Dr. Smith says hi."], "e.g. this one"),
        ('She said "Go!" Then left', ['She said "Go!"'], "Then left"),
        ("first part\n\nsecond", ["first part"], "second"),
        ("  \n ", [], ""),
        ("v1.2.3 is out", [], "v1.2.3 is out"),
    ],
)
def test_split_sentences(buffer: str, sentences: list[str], rest: str) -> None:
    assert split_sentences(buffer) == (sentences, rest)


def test_long_text_without_terminator_is_cut_at_spaces_and_bounded() -> None:
    sentences, rest = split_sentences("word, " * 100, max_chars=40)
    assert all(len(s) <= 40 for s in sentences) and len(rest) <= 40
    assert all(s.endswith(",") for s in sentences)
    assert " ".join([*sentences, rest]).split() == ("word, " * 100).split()
    sentences, rest = split_sentences("x" * 95, max_chars=40)
    assert sentences == ["x" * 40, "x" * 40] and rest == "x" * 15


def test_bad_max_chars() -> None:
    with pytest.raises(ValueError, match="max_chars"):
        split_sentences("x", max_chars=0)


ALPHABET = st.sampled_from(list("ab3 .!?…。！？，,\n\"」") + ["Dr", "e.g", "你", "好"])


@settings(max_examples=300, deadline=None)
@given(st.lists(ALPHABET, max_size=60), st.lists(st.integers(0, 60), max_size=8), st.integers(3, 30))
def test_streaming_split_does_not_depend_on_chunking(parts: list[str], cuts: list[int], max_chars: int) -> None:
    text = "".join(parts)
    # a terminator run longer than max_chars must be split somewhere: the one chunk-dependent case
    assume(not re.search("[.!?…。！？\"」]{%d}" % (max_chars + 1), text))
    whole = SentenceSplitter(max_chars)
    expected = whole.feed(text) + whole.flush()
    bounds = sorted({min(c, len(text)) for c in cuts} | {0, len(text)})
    chunked = SentenceSplitter(max_chars)
    got: list[str] = []
    for a, b in zip(bounds, bounds[1:]):
        got += chunked.feed(text[a:b])
        assert len(chunked.pending) <= max_chars
    got += chunked.flush()
    assert got == expected
    assert "".join(got).replace(" ", "").replace("\n", "") == text.replace(" ", "").replace("\n", "")


def test_an_over_long_cut_keeps_what_decides_the_next_terminator() -> None:
    """Found by the property test: a streamed tail cut between a CJK character and its ellipsis used to
    lose the character that makes the ellipsis end the sentence (``…a`` instead of ``…`` + ``a``)."""
    text = "a。aa你…a"
    whole = SentenceSplitter(3)
    chunked = SentenceSplitter(3)
    expected = whole.feed(text) + whole.flush()
    assert expected == ["a。", "aa你", "…", "a"]
    assert chunked.feed(text[:6]) + chunked.feed(text[6:]) + chunked.flush() == expected
