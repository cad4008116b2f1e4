"""A link for driving :class:`host.motion.streamer.FrameStreamer` without a board: the board clock stands
where the test puts it, messages are recorded, not sent (the streamer's ``FrameLink`` seam), and a
ramp motion to start on it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from protocol.messages import ServoFrame

__all__ = ["TICK_US", "Ramp", "RecordingLink"]

TICK_US = 2_000


@dataclass
class RecordingLink:
    """The streamer's link: board time stands at ``now_us``; messages are recorded, not sent."""

    now_us: int = 1_000_000
    uplink_us: int = 300
    lockstep: bool = False
    sent: list[object] = field(default_factory=list)

    @property
    def tick_us(self) -> int:
        return TICK_US

    def board_now_us(self) -> int:
        return self.now_us

    #: wire time per byte (µs) added to the latency, as a modelled line's (0: none)
    us_per_byte: float = 0.0

    def latency_us(self, nbytes: int = 0, q: float = 0.99) -> int:
        """The same for every quantile ``q``: this link's uplink does not vary."""
        return self.uplink_us + round(self.us_per_byte * nbytes)

    def send_start(self, frame: ServoFrame) -> int:
        self.sent += [frame, ("FLUSH", frame.apply_at_us + 1, frame.mask)]
        return len(self.sent) - 1

    def queue_frame(self, frame: ServoFrame, on_sent: Callable[[int], None] | None = None) -> None:
        self.sent.append(frame)

    async def flush(self, from_us: int, mask: int) -> None:
        """An awaited FLUSH (a cut's): recorded, ACKed at once."""
        self.sent.append(("FLUSH", from_us, mask))


@dataclass(frozen=True)
class Ramp:
    """A motion of servos 0 and 1 from 0 to 0.5 rad over 0.2 s (the mixer's ``MotionLike``)."""

    servos: tuple[int, ...] = (0, 1)
    t: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.2]))
    q: np.ndarray = field(default_factory=lambda: np.array([[0.0, 0.0], [0.5, 0.5]]))
    loop_from: float | None = None
