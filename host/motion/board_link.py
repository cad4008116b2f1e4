"""The streamer's link (:class:`host.motion.streamer.FrameLink`) over a :class:`host.link.BoardClient`."""

from __future__ import annotations

import time

from host.link import BoardClient
from protocol.messages import Flush, ServoFrame
from protocol.wiremodel import WireModel

#: One-way latency (µs) assumed before any TIME_SYNC round trip was measured.
DEFAULT_LATENCY_US = 2_000


class BoardFrameLink:
    """Frames, flushes and the board clock of a :class:`BoardClient`, as the streamer needs them.

    ``wire_baud``: the baud rate the board models wire time at (its ``--baud``), or None for a
    plain pty; it adds ``10 * nbytes / wire_baud`` to :meth:`latency_us`.
    """

    def __init__(self, client: BoardClient, wire_baud: int | None = None) -> None:
        self.client = client
        self.wire_baud = wire_baud
        if wire_baud and client.tx_wire is None:  # the host models its own line from now on
            client.tx_wire = WireModel(wire_baud)

    @property
    def lockstep(self) -> bool:
        return self.client.lockstep

    @property
    def tick_us(self) -> int:
        caps = self.client.caps
        return 1_000_000 // caps.control_rate_hz if caps is not None and caps.control_rate_hz else 2_000

    def board_now_us(self) -> int:
        return self.client.board_now_estimate()

    def latency_us(self, nbytes: int = 0) -> int:
        """Host -> board latency p99 (µs) for a message of ``nbytes`` sent now: the p99 of the TIME_SYNC
        requests' measured uplink beyond the line (``ClockSync.uplink_quantile``), plus, with
        ``wire_baud``, how long the line is still busy with bytes sent before (the host's model of it,
        ``BoardClient.tx_wire``: known now, not a p99 of past queues) and the message's own wire time
        (``10 * nbytes / wire_baud``, 8N1)."""
        up = self.client.clock.uplink_quantile(0.99)
        one_way = DEFAULT_LATENCY_US if up is None else up
        wire = 10e6 * nbytes / self.wire_baud if self.wire_baud else 0.0
        line = self.client.tx_wire
        backlog = line.busy_s(time.monotonic()) * 1e6 if line is not None else 0.0
        return int(one_way + backlog + wire)

    async def send_frame(self, frame: ServoFrame) -> int:
        return self.client.send_frame(frame)

    async def flush(self, from_us: int, mask: int) -> None:
        await self.client.flush(from_us, mask)

    def send_flush(self, from_us: int, mask: int) -> None:
        self.client.send(Flush(int(from_us), int(mask)))
