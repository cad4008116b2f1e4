"""Jitter buffer: timed servo frames ordered by apply-at time on the board clock.

Frames are kept sorted by ``(apply_at_us, arrival order)``: a later-arriving frame
with the same apply-at time overrides an earlier one for the servos both cover.
Capacity is fixed; the caller gets ``False`` from :meth:`JitterBuffer.push` when full.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

__all__ = ["BufferedFrame", "JitterBuffer"]


@dataclass(order=True)
class BufferedFrame:
    """One accepted SERVO_FRAME; ``values`` maps servo index -> target (rad)."""

    apply_at_us: int
    order: int
    seq: int = field(compare=False)
    values: dict[int, float] = field(compare=False)


class JitterBuffer:
    """Bounded, time-ordered store of frames with a per-servo "next keyframe" lookup."""

    def __init__(self, capacity: int, n_servos: int) -> None:
        self.capacity = capacity
        self.n_servos = n_servos
        self._frames: list[BufferedFrame] = []
        self._order = 0
        self._next_cache: list[tuple[int, float] | None] | None = None

    def __len__(self) -> int:
        return len(self._frames)

    @property
    def latest_apply_at(self) -> int | None:
        """Apply-at time of the last buffered frame (None when empty)."""
        return self._frames[-1].apply_at_us if self._frames else None

    @property
    def first_apply_at(self) -> int | None:
        """Apply-at time of the earliest buffered frame (None when empty): nothing is due before it."""
        return self._frames[0].apply_at_us if self._frames else None

    def pending_for(self, servo: int) -> bool:
        return self.next_for(servo) is not None

    def push(self, apply_at_us: int, seq: int, values: dict[int, float]) -> bool:
        """Insert a frame; ``False`` (nothing stored) when the buffer is full."""
        if len(self._frames) >= self.capacity:
            return False
        self._order += 1
        frame = BufferedFrame(apply_at_us, self._order, seq, dict(values))
        if not self._frames or apply_at_us >= self._frames[-1].apply_at_us:
            self._frames.append(frame)  # in time order (the usual stream): where insort would put it
        else:
            bisect.insort(self._frames, frame)
        self._next_cache = None
        return True

    def pop_due(self, t_us: int) -> list[BufferedFrame]:
        """Remove and return every frame with ``apply_at_us <= t_us``, in order."""
        if not self._frames or self._frames[0].apply_at_us > t_us:
            return []
        n = 0
        while n < len(self._frames) and self._frames[n].apply_at_us <= t_us:
            n += 1
        if not n:
            return []
        due, self._frames = self._frames[:n], self._frames[n:]
        self._next_cache = None
        return due

    def next_for(self, servo: int) -> tuple[int, float] | None:
        """(apply_at, target) of the earliest buffered frame covering ``servo``."""
        if self._next_cache is None:
            cache: list[tuple[int, float] | None] = [None] * self.n_servos
            missing = self.n_servos
            for f in self._frames:
                for i, v in f.values.items():
                    if cache[i] is None:
                        cache[i] = (f.apply_at_us, v)
                        missing -= 1
                if not missing:
                    break
            self._next_cache = cache
        return self._next_cache[servo]

    def flush(self, from_us: int, mask: int) -> set[int]:
        """Drop targets due at or after ``from_us`` for the masked servos; returns the servos touched."""
        touched: set[int] = set()
        kept: list[BufferedFrame] = []
        for f in self._frames:
            if f.apply_at_us >= from_us:
                for i in [i for i in f.values if mask >> i & 1]:
                    del f.values[i]
                    touched.add(i)
                if not f.values:
                    continue
            kept.append(f)
        self._frames = kept
        self._next_cache = None
        return touched

    def next_all(self) -> list[tuple[int, float] | None]:
        """:meth:`next_for` of every servo at once (cached until the buffer changes; do not modify)."""
        if self._next_cache is None:
            self.next_for(0)
        assert self._next_cache is not None
        return self._next_cache

    def clear(self) -> None:
        self._frames.clear()
        self._next_cache = None
