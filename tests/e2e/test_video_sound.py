"""run.mp4's sound: an AAC track with the robot's speech at the timeline's speak intervals (±100 ms),
music stand-ins under it, speech cut where an interruption cut it, and a silent track without espeak-ng."""

from __future__ import annotations

import json
import logging
import re
import shutil
import subprocess
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest

from host.run.soundtrack import SAMPLE_RATE, build_soundtrack, rms_windows, stand_in
from host.run.video import VideoSettings, render_video

from .conftest import run_e2e

WINDOW_S = 0.020
SPEECH_RMS = 0.06  # a 20 ms window this loud is speech (the music stand-ins stay below 0.05)
TOLERANCE_S = 0.100

pytestmark = pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="espeak-ng is not installed")


def _probe(path: Path) -> str:
    """What ffmpeg says about the file's streams (imageio-ffmpeg ships ffmpeg, not ffprobe: ``ffmpeg -i``)."""
    proc = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(path)],
                          capture_output=True, text=True, check=False)
    return proc.stderr


def _audio(path: Path) -> np.ndarray:
    """The file's audio track decoded to mono float samples at SAMPLE_RATE."""
    proc = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-i", str(path), "-vn", "-ac", "1",
                           "-ar", str(SAMPLE_RATE), "-f", "s16le", "-"], capture_output=True, check=True)
    return np.frombuffer(proc.stdout, dtype="<i2").astype(np.float32) / 32768.0


def _intervals(run_dir: Path, function: str) -> list[tuple[float, float]]:
    doc = json.loads((run_dir / "timeline.json").read_text())
    return [(c["start"], c["end"]) for c in doc["calls"] if c["function"] == function and c["start"] is not None]


def _loud_times(samples: np.ndarray, start_s: float) -> np.ndarray:
    """Board times (window centres) of the 20 ms windows loud enough to be speech."""
    r = rms_windows(samples, WINDOW_S)
    return start_s + (np.flatnonzero(r > SPEECH_RMS) + 0.5) * WINDOW_S


def _inside(t: float, spans: list[tuple[float, float]], tol: float = TOLERANCE_S) -> bool:
    return any(a - tol <= t <= b + tol for a, b in spans)


def test_run_mp4_speaks_at_the_timeline_speak_intervals(tmp_path: Path) -> None:
    run = run_e2e('Hello there, I am CoCo.<play_bgm name="happy" duration="2.5" volume="100"/>'
                  '<head_act action="nod"/>Nice to meet you.', tmp_path, settle_s=0.3)
    path = render_video(run.out, settings=VideoSettings(fps=10, workers=1))
    probe = _probe(path)
    assert re.search(r"Stream #0:\d.*Video: h264", probe) and re.search(r"Stream #0:\d.*Audio: aac", probe), probe
    samples = _audio(path)
    start = max(run.telemetry[0][0], run.t0)  # the video's first frame, and the track's first sample
    speak = _intervals(run.out, "speak")
    music = _intervals(run.out, "play_bgm")
    assert len(speak) == 2 and len(music) == 1
    loud = _loud_times(samples, start)
    # speech energy lies inside the speak intervals (±100 ms) and nowhere else
    outside = [round(t, 3) for t in loud if not _inside(t, speak)]
    assert not outside, f"speech energy outside the speak intervals {speak}: {outside}"
    # each sentence is heard from its start on: its first loud window within 100 ms of the call's start
    for a, b in speak:
        mine = loud[(loud >= a - TOLERANCE_S) & (loud <= b + TOLERANCE_S)]
        assert len(mine) > 10 and abs(mine[0] - a) <= TOLERANCE_S, (a, mine[:3])
    # between the sentences the music plays: present, below the speech threshold
    gap = (speak[0][1] + 0.05, speak[1][0] - 0.05)
    if gap[1] - gap[0] >= 0.04 and music[0][0] <= gap[0] and gap[1] <= music[0][1]:
        seg = samples[int((gap[0] - start) * SAMPLE_RATE):int((gap[1] - start) * SAMPLE_RATE)]
        assert 0.005 < float(np.sqrt(np.mean(seg ** 2))) < SPEECH_RMS
    # after everything: silence
    last = max(b for _, b in speak + music)
    tail = samples[int((last + 0.15 - start) * SAMPLE_RATE):]
    assert len(tail) == 0 or float(np.abs(tail).max()) < 0.02
    assert len(samples) / SAMPLE_RATE == pytest.approx(run.telemetry[0][-1] - start + 0.1, abs=0.15)  # the video's length


def test_interrupted_speech_stops_where_the_board_stopped_it(tmp_path: Path) -> None:
    run = run_e2e("Hello there. This sentence is long enough to be cut somewhere in the middle by the user.",
                  tmp_path, interrupt_at=2.2, settle_s=0.3)
    speak = [c for c in run.calls if c.function == "speak" and c.start is not None]
    cut = [c for c in speak if c.outcome != "done"]
    assert cut, run.table()
    start = max(run.telemetry[0][0], run.t0)
    st = build_soundtrack(run.out, start, run.telemetry[0][-1] - start)
    loud = _loud_times(st.samples, start)
    assert len(loud) and loud[-1] <= cut[0].end + TOLERANCE_S
    # the full sentence would have gone on: its own WAV is longer than what was placed
    placed = next(p for p in st.speech if p[2] == cut[0].args["text"])
    assert placed[1] == pytest.approx(cut[0].end, abs=1.0 / SAMPLE_RATE)


def test_without_espeak_the_video_is_silent_with_one_warning(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                             caplog: pytest.LogCaptureFixture) -> None:
    run = run_e2e("Hello.", tmp_path, settle_s=0.2)
    shutil.rmtree(run.out / "speech")  # as if the run had no espeak-ng either
    import host.speech.tts as tts

    monkeypatch.setattr(tts, "espeak_path", lambda: None)
    with caplog.at_level(logging.WARNING, logger="host.run"):
        path = render_video(run.out, settings=VideoSettings(fps=5, workers=1))
    notes = [r.getMessage() for r in caplog.records]
    assert len(notes) == 1 and "espeak-ng is not installed" in notes[0]
    assert "Audio: aac" in _probe(path)
    assert float(np.abs(_audio(path)).max()) < 0.01


def test_music_stand_ins_are_deterministic_per_name() -> None:
    a, b = stand_in("happy", 1.0), stand_in("happy", 1.0)
    assert np.array_equal(a, b) and len(a) == SAMPLE_RATE
    assert not np.allclose(a, stand_in("sad", 1.0))
    assert float(rms_windows(stand_in("anything", 2.0, volume=100)).max()) < SPEECH_RMS
