"""The streamer's transmit queue for a slow line: servo frames leave earliest apply time first.

Sans-I/O (no clock, no link): :class:`host.motion.board_link.BoardFrameLink` holds frames here and
writes them one at a time as its model of the line drains (``BoardClient.tx_wire``).

Why: over a UART of 115 200 baud (the emulated board's ``--baud``) a 12-servo SERVO_FRAME (39
bytes) is 3.4 ms of wire. Written at once, the frames the streamer sends ahead (the 60 ms lookahead,
and the grid a just-started motion re-sends for its servos) sit in the line's FIFO, and a new call's
FLUSH and first frame wait behind up to ~20 ms of them. Held here, unwritten, a message that is due
sooner (the new call's FLUSH and first frame, which the link writes at once) overtakes them.

Why the board ends up with the same frames as if every frame had been written when it was queued
(a FIFO): the board's jitter buffer (``firmware_sim.jitter_buffer``, the C firmware's ``jbuf``)
orders frames by (apply time, arrival), so frames written in (apply time, queue order) order leave
the buffer a FIFO would have left, except for a FLUSH written while frames queued before it are
still held here. :meth:`EdfFrameQueue.flush` does to those frames what the board's flush would have
done to them had they been written first: it removes the masked servos from every held frame due
at or after ``from_us`` (a frame left with no servo is dropped). Frames queued after the FLUSH are
not touched, as on the board.

What is equal is the buffer's contents: frames written later than a FIFO would have written them
still have to arrive before their apply time (the pacing writes the one due first, and the streamer
plans a new motion behind the line's backlog), or the board answers LATE as it would to any late
frame. The argument needs one rule of the link: before a frame is written at once, past the held ones
(``BoardFrameLink.send_start``), the held frames lose its servos from its apply time on (the FLUSH
that follows it on the wire starts just after that time, so it leaves the frame alone), so no held
frame of the same apply time can later override it.

Sequence numbers are given when a frame is written, so among held frames they rise with apply time
(a frame written at once may overtake held ones due earlier); the streamer confirms a frame only
once the board's ``last_applied_seq`` has passed it *and* board time has reached it
(``host.motion.streamer.FrameStreamer.on_telemetry``).
A frame's ``on_sent`` callback gets its number; a dropped frame's callback gets the number of the
next frame written (the board is past the dropped frame once it applied that one, as it would be past
a frame it flushed).

Bounded: :meth:`EdfFrameQueue.push` refuses a frame when ``capacity`` frames are held; the caller
then writes the held frame due first (what the pacing would write next) and pushes again, so nothing
is lost and the order argument above still holds.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable
from dataclasses import dataclass

from protocol.messages import ServoFrame

__all__ = ["DEFAULT_CAPACITY", "EdfFrameQueue", "SeqCallback"]

#: a frame's on_sent callback: called with the sequence number the frame was written with
SeqCallback = Callable[[int], None]

#: frames held at most (the streamer holds ~6 lookahead frames plus ~6 re-sent per started motion)
DEFAULT_CAPACITY = 256


@dataclass
class _Held:
    apply_at_us: int
    mask: int
    targets: list[float]  # one per set bit of mask, in ascending servo order (as ServoFrame)
    on_sent: list[SeqCallback]


class EdfFrameQueue:
    """Servo frames held unwritten, popped earliest ``apply_at_us`` first (ties: in queue order)."""

    def __init__(self, capacity: int = DEFAULT_CAPACITY) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self.capacity = capacity
        self._heap: list[tuple[int, int, _Held]] = []
        self._order = itertools.count()
        self._live = 0  # held frames with at least one servo
        self._orphans: list[SeqCallback] = []  # callbacks of dropped frames, for the next frame written
        #: frames dropped whole by a FLUSH (the board would have flushed them)
        self.dropped = 0

    def __len__(self) -> int:
        """Frames held (not counting ones a FLUSH emptied)."""
        return self._live

    def push(self, frame: ServoFrame, on_sent: SeqCallback | None = None) -> bool:
        """Hold ``frame``; False (nothing held) when ``capacity`` frames are held already."""
        if self._live >= self.capacity or len(self._heap) >= 2 * self.capacity:  # emptied frames count too
            return False
        held = _Held(int(frame.apply_at_us), int(frame.mask), list(frame.targets), [on_sent] if on_sent else [])
        heapq.heappush(self._heap, (held.apply_at_us, next(self._order), held))
        self._live += 1
        return True

    def next_apply_at(self) -> int | None:
        """Apply time (µs) of the frame :meth:`pop` would give, None when none is held."""
        self._drop_empty_head()
        return self._heap[0][0] if self._heap else None

    def pop(self) -> tuple[ServoFrame, list[SeqCallback]] | None:
        """The held frame due first and the callbacks to call with the number it is written with
        (its own, then those of frames dropped since the last pop); None when none is held."""
        self._drop_empty_head()
        if not self._heap:
            return None
        _, _, held = heapq.heappop(self._heap)
        self._live -= 1
        callbacks = held.on_sent + self._orphans
        self._orphans = []
        return ServoFrame(held.apply_at_us, held.mask, tuple(held.targets)), callbacks

    def flush(self, from_us: int, mask: int) -> None:
        """Remove the ``mask`` servos from every held frame due at or after ``from_us`` (µs), as the
        board's FLUSH would once the frame was in its buffer; a frame left with none is dropped."""
        for apply_at, _, held in self._heap:
            if apply_at < from_us or not held.mask & mask:
                continue
            keep_mask = held.mask & ~mask
            kept: list[float] = []
            bits = held.mask
            for value in held.targets:
                bit = bits & -bits
                bits ^= bit
                if keep_mask & bit:
                    kept.append(value)
            held.mask, held.targets = keep_mask, kept
            if not keep_mask:
                self._live -= 1
                self.dropped += 1
                self._orphans.extend(held.on_sent)
                held.on_sent = []

    def held(self) -> list[ServoFrame]:
        """The held frames in the order :meth:`pop` would give them (nothing is removed)."""
        live = sorted((a, o, h) for a, o, h in self._heap if h.mask)
        return [ServoFrame(h.apply_at_us, h.mask, tuple(h.targets)) for _, _, h in live]

    def drain(self) -> list[tuple[ServoFrame, list[SeqCallback]]]:
        """Every held frame in the order :meth:`pop` gives them (the queue is empty afterwards)."""
        out = []
        while (item := self.pop()) is not None:
            out.append(item)
        return out

    def adopt(self, callbacks: list[SeqCallback]) -> None:
        """Hand ``callbacks`` (of a frame that could not be written) to the next frame written."""
        self._orphans.extend(callbacks)

    def take_orphans(self) -> list[SeqCallback]:
        """Callbacks of dropped frames not yet handed to a written frame (the queue forgets them)."""
        orphans, self._orphans = self._orphans, []
        return orphans

    def _drop_empty_head(self) -> None:
        while self._heap and not self._heap[0][2].mask:
            heapq.heappop(self._heap)
