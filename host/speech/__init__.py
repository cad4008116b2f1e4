"""Speech for the ``speech`` channel: sentence splitting and TTS durations."""

from __future__ import annotations

from host.speech.sentences import MAX_CHARS, SentenceSplitter, split_sentences
from host.speech.tts import (
    DEFAULT_RATE_WPM,
    SpeechError,
    Utterance,
    default_voice,
    espeak_path,
    estimate_duration_s,
    synthesize,
    synthesize_async,
    wav_duration_s,
)

__all__ = [
    "DEFAULT_RATE_WPM",
    "MAX_CHARS",
    "SentenceSplitter",
    "SpeechError",
    "Utterance",
    "default_voice",
    "espeak_path",
    "estimate_duration_s",
    "split_sentences",
    "synthesize",
    "synthesize_async",
    "wav_duration_s",
]
