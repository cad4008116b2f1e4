"""python-can issue #2004: SocketCAN refuses sends with ENOBUFS when the tx queue is full.

This kernel has no vcan, so the refusal is reproduced by a python-can virtual bus whose ``send``
raises exactly what python-can's socketcan interface raises then (``CanOperationError`` with
``error_code`` ENOBUFS). Both ends must retry: nothing lost, order kept, no crash.
"""

from __future__ import annotations

import asyncio
import errno
import threading

import can
import pytest
from can.interfaces.virtual import VirtualBus

from firmware_sim.board import Board
from firmware_sim.config import BoardConfig
from firmware_sim.server import BoardServer
from firmware_sim.transports.can import BusBoardTransport
from host.link import BoardClient
from host.link.moves import move_to
from host.link.transports.can import CanLinkTransport
from protocol.linkspec import parse_link_spec
from robots.coco import load_poses

pytestmark = pytest.mark.timeout(60)


class FullQueueBus(VirtualBus):
    """Refuses every ``every``-th send with ENOBUFS, as SocketCAN does on a full tx queue."""

    def __init__(self, *args: object, every: int = 3, **kw: object) -> None:
        super().__init__(*args, **kw)  # type: ignore[arg-type]
        self.every = every
        self.calls = 0
        self.refused = 0

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.calls += 1
        if self.calls % self.every == 0:
            self.refused += 1
            raise can.CanOperationError("Failed to transmit: [Errno 105] No buffer space available", errno.ENOBUFS)
        super().send(msg, timeout)


def test_both_ends_retry_on_enobufs(virtual_channel: str) -> None:
    spec = parse_link_spec(f"can:virtual:{virtual_channel}")
    board_bus = FullQueueBus(channel=virtual_channel, every=4)
    transport = BusBoardTransport(spec, bus=board_bus)
    server = BoardServer(Board(BoardConfig(lockstep=True)), transport)
    th = threading.Thread(target=server.serve, daemon=True)
    th.start()
    host_bus = FullQueueBus(channel=virtual_channel, every=3)
    try:
        async def main() -> None:
            host = CanLinkTransport(spec, bus=host_bus)
            async with await BoardClient.connect(spec, transport=host) as c:
                res = await move_to(c, load_poses()["sit"], duration_s=0.5)
                assert res.max_error_deg < 3.0
                assert c.stats.decode_errors == 0 and c.stats.frame_nacks == 0
                assert host.tx_retries > 0 and host_bus.refused > 0
                t = c.latest_telemetry
                assert t is not None and t.link_errors == 0  # the board never saw a partial frame

        asyncio.run(main())
        assert transport.tx_retries > 0 and board_bus.refused > 0
        assert transport.decoder.error_count == 0
    finally:
        server.stop()
        th.join(5)
        transport.close()
        host_bus.shutdown()
