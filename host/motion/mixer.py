"""Compose per-channel motions into timed full-body servo frames.

The mixer is pure bookkeeping: no I/O and no clock. The streamer asks it for the
frame at board time ``t`` (microseconds), every frame period, a little ahead of
the board. Each servo follows the newest active segment that drives it (a
descendant call that takes over a persistent parent's servos wins while it
runs, and the parent's loop shows through again when it ends); a servo that no
segment drives holds its last target.

A segment is a motion (see :class:`MotionLike`) placed at a start time on the
board clock. Finite segments end at ``start + t[-1]``; looping segments (the
persistent form of a behaviour) repeat ``[loop_from, t[-1]]`` until
:meth:`Mixer.release` cuts them. The mixer reports, per frame, which segments
appear in it for the first and for the last time, so the streamer can tell
from telemetry when a call really started and ended on the board.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np


class MotionLike(Protocol):
    """What the mixer needs of a motion (``robots.motion.Motion`` fits)."""

    @property
    def servos(self) -> tuple[int, ...]: ...

    @property
    def t(self) -> np.ndarray: ...

    @property
    def q(self) -> np.ndarray: ...

    @property
    def loop_from(self) -> float | None: ...


@dataclass(eq=False)
class Segment:
    """A motion placed on the board clock."""

    id: int
    motion: MotionLike
    start_us: int
    label: str = ""
    release_us: int | None = None  # a looping segment stops here
    first_frame_us: int | None = None  # set once the segment appears in a frame
    last_frame_us: int | None = None  # set once the segment has appeared for the last time
    servos: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.servos = np.asarray(self.motion.servos, dtype=int)
        if len(self.motion.t) == 0 or self.motion.t[0] != 0.0:
            raise ValueError(f"segment {self.label!r}: motion times must start at 0")

    @property
    def looping(self) -> bool:
        return self.motion.loop_from is not None

    @property
    def end_us(self) -> int | None:
        """Board time of the last target, or None while a loop runs unreleased."""
        if self.release_us is not None:
            return self.release_us
        if self.looping:
            return None
        return self.start_us + int(round(float(self.motion.t[-1]) * 1e6))

    def active_at(self, t_us: int) -> bool:
        end = self.end_us
        return t_us >= self.start_us and (end is None or t_us <= end)

    def sample(self, t_us: int) -> np.ndarray:
        """Targets of this segment's servos at board time ``t_us``."""
        m = self.motion
        tr = (t_us - self.start_us) * 1e-6
        t_end = float(m.t[-1])
        if m.loop_from is not None and tr > t_end:
            period = t_end - m.loop_from
            tr = t_end if period <= 0 else m.loop_from + (tr - m.loop_from) % period
        tr = min(max(tr, 0.0), t_end)
        i = int(np.searchsorted(m.t, tr, side="right"))
        if i <= 0:
            return np.asarray(m.q[0], dtype=float)
        if i >= len(m.t):
            return np.asarray(m.q[-1], dtype=float)
        t0, t1 = m.t[i - 1], m.t[i]
        w = (tr - t0) / (t1 - t0)
        return (1.0 - w) * m.q[i - 1] + w * m.q[i]


@dataclass(frozen=True)
class MixedFrame:
    """One full-body frame and the segments it starts and ends."""

    t_us: int
    targets: np.ndarray
    started: tuple[Segment, ...]
    ended: tuple[Segment, ...]


class Mixer:
    """Per-servo priority mix of segments into full frames."""

    def __init__(self, initial: Iterable[float]) -> None:
        self.held = np.array(list(initial), dtype=float)
        self._segments: list[Segment] = []
        self._ids = itertools.count(1)

    @property
    def n_servos(self) -> int:
        return len(self.held)

    @property
    def segments(self) -> tuple[Segment, ...]:
        """Segments not yet finished (including ones that start later)."""
        return tuple(self._segments)

    def add(self, motion: MotionLike, start_us: int, label: str = "") -> Segment:
        """Place ``motion`` at board time ``start_us``; newer segments override older ones."""
        if len(motion.servos) and max(motion.servos) >= self.n_servos:
            raise ValueError(f"segment {label!r}: servo index out of range")
        seg = Segment(next(self._ids), motion, int(start_us), label)
        self._segments.append(seg)
        return seg

    def release(self, seg: Segment, at_us: int) -> None:
        """Stop ``seg`` at board time ``at_us`` (a looping segment's reset, or an interruption)."""
        end = seg.end_us
        at = max(int(at_us), seg.start_us)
        seg.release_us = at if end is None else min(end, at)

    def cancel(self, seg: Segment) -> None:
        """Drop ``seg`` entirely if it has not appeared in any frame, else release it now-ish."""
        if seg.first_frame_us is None and seg in self._segments:
            self._segments.remove(seg)
            seg.release_us = seg.start_us
        elif seg.first_frame_us is not None and seg.last_frame_us is None:
            seg.release_us = seg.first_frame_us if seg.release_us is None else seg.release_us

    def sample_servo_targets(self, t_us: int) -> np.ndarray:
        """Targets at ``t_us`` without producing a frame (for planning the next motion's start)."""
        out = self.held.copy()
        for seg in self._segments:
            if seg.active_at(t_us):
                out[seg.servos] = seg.sample(t_us)
        return out

    def frame(self, t_us: int) -> MixedFrame:
        """The frame at board time ``t_us``; call with increasing times."""
        started: list[Segment] = []
        ended: list[Segment] = []
        out = self.held.copy()
        keep: list[Segment] = []
        for seg in self._segments:  # oldest first, so newer segments overwrite
            end = seg.end_us
            if t_us < seg.start_us:
                keep.append(seg)
                continue
            out[seg.servos] = seg.sample(min(t_us, end) if end is not None else t_us)
            if seg.first_frame_us is None:
                seg.first_frame_us = t_us
                started.append(seg)
            if end is not None and t_us >= end:
                seg.last_frame_us = t_us
                ended.append(seg)
            else:
                keep.append(seg)
        self._segments = keep
        self.held = out
        return MixedFrame(t_us, out.copy(), tuple(started), tuple(ended))
