"""A realtime board that cannot keep up with its control rate still serves its link.

The board's loop catches up on late ticks without sleeping. It used to read and write the link only
once caught up, so a board behind real time (a loaded machine, a User-Mode Linux guest sharing one
CPU) went silent for as long as it stayed behind: in CI a board inside UML missed every ISO-TP flow
control of its CAPS for 20 s and the handshake failed. Here the board's clock runs a 10 us control
period, which no tick meets, and never re-anchors, so the board is behind for the whole test: a host
must still get its CAPS, TELEMETRY and the replies to its requests. Real pty, real pyserial host
(:class:`host.link.BoardClient`), the board served in a thread of this process.
"""

from __future__ import annotations

import asyncio
import math
import threading

import pytest

from firmware_sim.board import Board
from firmware_sim.clock import RealtimeClock
from firmware_sim.config import BoardConfig
from firmware_sim.server import BoardServer
from firmware_sim.transports.serial import SerialBoardTransport
from host.link import BoardClient
from protocol.messages import ConfigKey


@pytest.mark.timeout(120)
def test_a_board_that_never_catches_up_still_answers() -> None:
    transport = SerialBoardTransport("pty")
    board = Board(BoardConfig(lockstep=False))
    server = BoardServer(board, transport)
    clock = RealtimeClock(period_s=10e-6, max_behind_s=math.inf)  # every tick late, no re-anchoring
    server.clock = clock
    board._clock_us = clock.board_time_us
    thread = threading.Thread(target=server.serve, name="board-behind", daemon=True)
    thread.start()
    try:
        async def main() -> tuple[int, int]:
            async with await BoardClient.connect(transport.name, handshake_timeout=30.0, reply_timeout=10.0) as c:
                first = await c.wait_for(lambda t: True, 30)
                await c.configure(ConfigKey.CROUCH_AFTER_MS, 60_000)  # a request, ACKed
                later = await c.wait_for(lambda t: t.board_time_us > first.board_time_us, 30)
                return first.board_time_us, later.board_time_us

        first_us, later_us = asyncio.run(main())
        assert later_us > first_us
        # the board was behind all along (a tick costs far more than 10 us, and the schedule never re-anchored)
        assert clock.resyncs == 0 and clock.time_to_deadline() < 0
    finally:
        server.stop()
        thread.join(10)
        transport.close()
    assert not thread.is_alive()
