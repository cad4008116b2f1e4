"""TTS durations: the real espeak-ng backend (where installed) and the words-per-minute model."""

from __future__ import annotations

import json

import wave
from pathlib import Path

import pytest
import trio
import trio.testing

from host.speech import SpeechError, Utterance, default_voice, espeak_path, estimate_duration_s, synthesize
from host.speech import synthesize_async

needs_espeak = pytest.mark.skipif(
    espeak_path() is None, reason="espeak-ng binary not installed (apt-get install espeak-ng)"
)

SAMPLES = [
    "Hello, I am CoCo.",
    "Let's do some exercise together, shall we?",
    "I will nod three times and then wave to you, my friend. Are you ready?",
    "你好，我是可可。",
    "我们一起做运动吧！今天天气很好。",
]


def test_model_counts_words_pauses_and_cjk_characters() -> None:
    assert estimate_duration_s("") == estimate_duration_s("   ") == 0.0
    one = estimate_duration_s("hello", 175)
    # each extra word adds WORD_WEIGHT nominal words
    assert estimate_duration_s("hello hello hello hello", 175) - one == pytest.approx(3 * 0.70 * 60 / 175)
    assert estimate_duration_s("hello, hello.", 175) > estimate_duration_s("hello hello", 175)  # pauses
    assert estimate_duration_s("hello", 120) == pytest.approx(one * 175 / 120)  # inverse in the rate
    assert estimate_duration_s("你好我是可可") - estimate_duration_s("你好") == pytest.approx(4 * 1.1 * 60 / 175)
    # "don't" and "3.5" are one word each; CJK characters are not words
    assert estimate_duration_s("don't stop") == estimate_duration_s("run now")


def test_model_backend_writes_nothing(tmp_path: Path) -> None:
    u = synthesize("Hello there, friend.", tmp_path, backend="wpm")
    assert u == Utterance("Hello there, friend.", estimate_duration_s("Hello there, friend."), None, "wpm")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("rate", [79, 451])
def test_rate_out_of_range_is_an_error(rate: int, tmp_path: Path) -> None:
    with pytest.raises(SpeechError, match="rate_wpm"):
        synthesize("hi", tmp_path, rate_wpm=rate)


def test_unknown_backend_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(SpeechError, match="unknown TTS backend"):
        synthesize("hi", tmp_path, backend="festival")  # type: ignore[arg-type]


def test_voice_follows_the_script() -> None:
    assert default_voice("Hello there") is None
    assert default_voice("你好，我是CoCo") == "cmn"
    assert default_voice("こんにちは") == "ja"
    assert default_voice("안녕하세요") == "ko"


def test_auto_backend_falls_back_to_the_model_without_espeak(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))  # no espeak-ng on this PATH
    assert espeak_path() is None
    assert synthesize("Hello.", tmp_path).backend == "wpm"
    with pytest.raises(SpeechError, match="apt-get install espeak-ng"):
        synthesize("Hello.", tmp_path, backend="espeak-ng")


@needs_espeak
def test_espeak_writes_a_wav_whose_duration_is_reported(tmp_path: Path) -> None:
    u = synthesize("Hello, I am CoCo. Nice to meet you!", tmp_path)
    assert u.backend == "espeak-ng" and u.wav_path is not None and u.wav_path.parent == tmp_path
    with wave.open(str(u.wav_path)) as w:
        assert w.getnframes() / w.getframerate() == u.duration_s
        assert w.getnchannels() == 1
    assert 1.0 < u.duration_s < 5.0
    again = synthesize("Hello, I am CoCo. Nice to meet you!", tmp_path)
    assert again == u and len(list(tmp_path.glob("*.wav"))) == 1  # same sentence, same file
    index = [json.loads(line) for line in (tmp_path / "index.jsonl").read_text().splitlines()]
    assert index == [{"wav": u.wav_path.name, "text": u.text, "voice": None, "rate_wpm": 175}]  # listed once


@needs_espeak
def test_espeak_rate_changes_the_duration(tmp_path: Path) -> None:
    text = "The quick brown fox jumps over the lazy dog."
    slow, fast = synthesize(text, tmp_path, rate_wpm=100), synthesize(text, tmp_path, rate_wpm=300)
    assert slow.duration_s > 2 * fast.duration_s
    assert slow.wav_path != fast.wav_path


@needs_espeak
@pytest.mark.parametrize("rate", [120, 175, 250])
def test_model_agrees_with_espeak(rate: int) -> None:
    errors = []
    for text in SAMPLES:
        real = synthesize(text, None, rate_wpm=rate).duration_s
        errors.append(abs(estimate_duration_s(text, rate) - real) / real)
    assert max(errors) < 0.35, errors
    assert sum(errors) / len(errors) < 0.2, errors


@needs_espeak
def test_espeak_mandarin_and_dash_text(tmp_path: Path) -> None:
    cn = synthesize("我们一起做运动吧！", tmp_path)
    assert cn.wav_path is not None and cn.duration_s > 1.0
    dash = synthesize("--help -v xx", tmp_path)  # text on stdin is never read as options
    assert dash.duration_s > 0.5


@needs_espeak
def test_espeak_unknown_voice_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(SpeechError, match="voice='zzqq'.*does not exist"):
        synthesize("hello", tmp_path, voice="zzqq")
    assert list(tmp_path.iterdir()) == []  # no partial file left behind


@needs_espeak
def test_empty_text_is_silence(tmp_path: Path) -> None:
    assert synthesize("  ", tmp_path) == Utterance("  ", 0.0, None, "espeak-ng")


def test_async_variant_runs_under_trio(tmp_path: Path) -> None:
    async def main() -> Utterance:
        return await synthesize_async("Hello.", tmp_path)

    u = trio.run(main, clock=trio.testing.MockClock(autojump_threshold=0))
    assert u.text == "Hello." and u.duration_s > 0
