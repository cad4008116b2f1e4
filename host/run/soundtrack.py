"""run.mp4's sound: the robot's speech and music where the board's timeline says they played, as an AAC track.

:func:`build_soundtrack` mixes a mono 16-bit WAV at :data:`SAMPLE_RATE` that starts at the video's
first frame (board time ``start_s``) and lasts as long as the video:

* speech: each ``speak`` call of ``timeline.json`` (board-measured start/end and its text). The sound is
  the WAV the runtime synthesised for that sentence during the run (espeak-ng, ``speech/``, found through
  ``speech/index.jsonl``, which :func:`host.speech.tts.synthesize` keeps); a sentence without one is
  synthesised now. It starts at the call's start and is cut at the call's end, so an interrupted
  sentence stops where the board stopped it (a 10 ms fade-out, no click).
* music and sound effects: each call of the robot's ``play_bgm`` behaviour (whatever its function is
  called in the run's vocabulary), from its start to its end, as a stand-in: no recordings are shipped
  or downloaded, so each clip name gets a short tune of its own (:func:`stand_in`: four notes of a
  pentatonic scale chosen by the name's SHA-256, looped, at the call's volume, kept well below speech).

:func:`mux_audio` adds the WAV to the video as AAC (ffmpeg's native encoder, from the ffmpeg binary of
``imageio-ffmpeg``), copying the H.264 stream. :func:`add_soundtrack` does both and replaces the video.

Without espeak-ng (and no WAV from the run) the speech is left out with one warning; the track stays
(silent where the speech was). Nothing here fails the video: problems come back as warning lines.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import tempfile
import wave
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["SAMPLE_RATE", "Soundtrack", "add_soundtrack", "build_soundtrack", "mux_audio", "rms_windows", "stand_in"]

#: espeak-ng's own output rate: its WAVs go in without resampling
SAMPLE_RATE = 22_050
#: music's peak level at volume 100 (speech from espeak-ng peaks near full scale)
MUSIC_LEVEL = 0.08
NOTE_S = 0.25
FADE_S = 0.010
#: the major pentatonic scale over two octaves (semitones above the tune's root)
PENTATONIC = (0, 2, 4, 7, 9, 12, 14, 16, 19, 21)
AAC_BITRATE = "96k"
MUSIC_BEHAVIOUR = "play_bgm"


@dataclass
class Soundtrack:
    """The mixed track: ``samples`` (float32, -1..1) from board time ``start_s``; ``notes``: warning lines."""

    samples: np.ndarray
    start_s: float
    speech: list[tuple[float, float, str]] = field(default_factory=list)  # (start, end, text) placed
    music: list[tuple[float, float, str]] = field(default_factory=list)  # (start, end, name) placed
    notes: list[str] = field(default_factory=list)

    def write_wav(self, path: Path) -> None:
        pcm = (np.clip(self.samples, -1.0, 1.0) * 32767).astype("<i2")
        with wave.open(str(path), "wb") as w:
            w.setnchannels(1)
            w.setsampwidth(2)
            w.setframerate(SAMPLE_RATE)
            w.writeframes(pcm.tobytes())


def stand_in(name: str, seconds: float, volume: float = 60.0) -> np.ndarray:
    """A deterministic tune for clip ``name``: 4 notes (root 196-392 Hz, pentatonic steps from SHA-256 of
    the name), :data:`NOTE_S` each, looped for ``seconds``; ``volume`` 0..100."""
    digest = hashlib.sha256(name.encode("utf-8")).digest()
    root = 196.0 * 2 ** (digest[0] / 255.0)
    freqs = [root * 2 ** (PENTATONIC[b % len(PENTATONIC)] / 12) for b in digest[1:5]]
    n = max(0, int(round(seconds * SAMPLE_RATE)))
    per = int(NOTE_S * SAMPLE_RATE)
    t = np.arange(per) / SAMPLE_RATE
    env = np.minimum(1.0, np.minimum(t / 0.01, (NOTE_S - t) / 0.05)).clip(0.0, 1.0)
    notes = [(np.sin(2 * np.pi * f * t) + 0.3 * np.sin(4 * np.pi * f * t)) / 1.3 * env for f in freqs]
    loop = np.concatenate(notes)
    reps = n // len(loop) + 1
    level = MUSIC_LEVEL * max(0.0, min(100.0, volume)) / 100.0
    return (np.tile(loop, reps)[:n] * level).astype(np.float32)


@dataclass(frozen=True)
class _Call:
    function: str
    start: float
    end: float
    args: dict[str, Any]
    outcome: str


def _timeline(run_dir: Path) -> list[_Call]:
    path = run_dir / "timeline.json"
    if not path.exists():
        return []
    doc = json.loads(path.read_text(encoding="utf-8"))
    return [_Call(str(c["function"]), float(c["start"]), float(c["end"]), dict(c.get("args") or {}), str(c.get("outcome")))
            for c in doc.get("calls", []) if c.get("start") is not None and c.get("end") is not None]


def _music_functions(run_dir: Path, robots_dir: str | None) -> dict[str, tuple[dict[str, str], dict[str, Any]]]:
    """Function name -> (stub param -> behaviour param, pinned behaviour params) of every stub the
    recorded robot implements with the music behaviour (any vocabulary)."""
    from host.run.artefacts import run_robot

    out: dict[str, tuple[dict[str, str], dict[str, Any]]] = {}
    try:
        from robots.registry import load_robot

        robot = load_robot(run_robot(run_dir), robots_dir)
        for vocab in robot.interface.names:
            for name, (_, info) in robot.interface.stubs(vocab).items():
                if info.behaviour == MUSIC_BEHAVIOUR:
                    out[name] = (dict(info.rename), dict(info.fixed))
    except Exception:  # an unloadable robot: the behaviour's own name still works
        pass
    out.setdefault(MUSIC_BEHAVIOUR, ({}, {}))
    return out


def _speech_index(run_dir: Path) -> dict[str, Path]:
    """text -> WAV the runtime synthesised for it (the latest one), from ``speech/index.jsonl``."""
    index = run_dir / "speech" / "index.jsonl"
    out: dict[str, Path] = {}
    try:
        lines = index.read_text(encoding="utf-8").splitlines()
    except OSError:
        return out
    for line in lines:
        try:
            rec = json.loads(line)
            wav = index.parent / str(rec["wav"])
        except (ValueError, KeyError, TypeError):
            continue
        if wav.exists():
            out[str(rec["text"])] = wav
    return out


def _read_wav(path: Path) -> np.ndarray:
    """A WAV as float32 mono at :data:`SAMPLE_RATE` (other rates resampled linearly)."""
    with wave.open(str(path), "rb") as w:
        rate, width, chans = w.getframerate(), w.getsampwidth(), w.getnchannels()
        data = w.readframes(w.getnframes())
    if width != 2:
        raise ValueError(f"{path.name}: {8 * width}-bit samples (16-bit expected)")
    x = np.frombuffer(data, dtype="<i2").astype(np.float32) / 32768.0
    if chans > 1:
        x = x.reshape(-1, chans).mean(axis=1)
    if rate != SAMPLE_RATE and len(x):
        n = int(round(len(x) * SAMPLE_RATE / rate))
        x = np.interp(np.arange(n) * rate / SAMPLE_RATE, np.arange(len(x)), x).astype(np.float32)
    return x


def _place(track: np.ndarray, sound: np.ndarray, at_s: float, until_s: float, start_s: float) -> tuple[float, float]:
    """Mix ``sound`` into ``track`` from board time ``at_s``, cut at ``until_s`` (faded); returns the span placed."""
    i0 = int(round((at_s - start_s) * SAMPLE_RATE))
    n = min(len(sound), max(0, int(round((until_s - at_s) * SAMPLE_RATE))))
    s = sound[:n].copy()
    if n < len(sound) and n > 0:  # cut short: fade out instead of a click
        k = min(n, int(FADE_S * SAMPLE_RATE))
        s[n - k:] *= np.linspace(1.0, 0.0, k, dtype=np.float32)
    lo, hi = max(0, i0), min(len(track), i0 + n)
    if hi > lo:
        track[lo:hi] += s[lo - i0:hi - i0]
    return at_s, at_s + n / SAMPLE_RATE


def build_soundtrack(run_dir: Path, start_s: float, duration_s: float, robots_dir: str | None = None) -> Soundtrack:
    """The run's sound from board time ``start_s`` for ``duration_s`` (see the module docstring)."""
    from host.speech.tts import SpeechError, espeak_path, synthesize

    run_dir = Path(run_dir)
    track = np.zeros(max(0, int(round(duration_s * SAMPLE_RATE))), dtype=np.float32)
    st = Soundtrack(track, start_s)
    calls = _timeline(run_dir)
    index = _speech_index(run_dir)
    music = _music_functions(run_dir, robots_dir)
    missing: list[str] = []
    with tempfile.TemporaryDirectory(prefix="ghostshell-soundtrack-") as tmp:
        for c in calls:
            if c.function == "speak" and str(c.args.get("text", "")).strip():
                text = str(c.args["text"])
                wav = index.get(text)
                if wav is None:
                    if espeak_path() is None:
                        missing.append(text)
                        continue
                    try:
                        wav = synthesize(text, tmp, backend="espeak-ng").wav_path
                    except SpeechError as e:
                        st.notes.append(f"ghostshell: no speech for {text[:40]!r} in run.mp4: {e}")
                        continue
                if wav is None:
                    continue
                try:
                    sound = _read_wav(wav)
                except (OSError, ValueError, wave.Error) as e:
                    st.notes.append(f"ghostshell: no speech for {text[:40]!r} in run.mp4: {wav.name}: {e}")
                    continue
                st.speech.append((*_place(track, sound, c.start, c.end, start_s), text))
            elif c.function in music:
                rename, fixed = music[c.function]
                args = {**{rename.get(k, k): v for k, v in c.args.items()}, **fixed}
                name = str(args.get("name", "happy"))
                volume = float(args.get("volume", 60) or 60)
                sound = stand_in(name, c.end - c.start, volume)
                st.music.append((*_place(track, sound, c.start, c.end, start_s), name))
    if missing:
        st.notes.append(f"ghostshell: run.mp4 has no speech: espeak-ng is not installed and the run left no "
                        f"speech WAVs ({len(missing)} sentence(s) silent; apt-get install espeak-ng)")
    np.clip(track, -1.0, 1.0, out=track)
    return st


def mux_audio(video: Path, wav: Path, out: Path) -> None:
    """``out`` = ``video``'s H.264 stream (copied) + ``wav`` encoded as AAC. Raises OSError with ffmpeg's reason."""
    import imageio_ffmpeg

    cmd = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-v", "error", "-i", str(video), "-i", str(wav),
           "-map", "0:v:0", "-map", "1:a:0", "-c:v", "copy", "-c:a", "aac", "-b:a", AAC_BITRATE,
           "-movflags", "+faststart", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False)
    if proc.returncode != 0 or not out.exists():
        raise OSError(f"ffmpeg could not add the sound: {(proc.stderr or '').strip().splitlines()[-1:] or proc.returncode}")


def add_soundtrack(run_dir: Path, video: Path, start_s: float, duration_s: float,
                   robots_dir: str | None = None) -> list[str]:
    """Give ``video`` its sound track in place; returns warning lines (the video stays silent on failure)."""
    st = build_soundtrack(run_dir, start_s, duration_s, robots_dir)
    notes = list(st.notes)
    video = Path(video)
    with tempfile.TemporaryDirectory(prefix="ghostshell-mux-", dir=video.parent) as tmp:
        wav = Path(tmp) / "sound.wav"
        muxed = Path(tmp) / f"muxed{video.suffix}"
        try:
            st.write_wav(wav)
            mux_audio(video, wav, muxed)
            os.replace(muxed, video)
        except OSError as e:
            notes.append(f"ghostshell: run.mp4 has no sound: {e}")
    return notes


def rms_windows(samples: np.ndarray, window_s: float = 0.020) -> np.ndarray:
    """RMS of consecutive ``window_s`` windows (for checking where the sound is)."""
    n = int(window_s * SAMPLE_RATE)
    k = len(samples) // n
    if k == 0:
        return np.zeros(0)
    return np.sqrt(np.mean(np.square(samples[:k * n].reshape(k, n), dtype=np.float64), axis=1))

