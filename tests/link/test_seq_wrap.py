"""16-bit sequence numbers across the wrap (issue 8): answers from one lap are never taken for the next.

A real lockstep board on a real pty: a frame with sequence S is NACKed; 65536 frames
later a valid frame goes out with sequence S again and the board applies it, so the
client must no longer report the old refusal for S.
"""

from __future__ import annotations

import asyncio

import pytest

from host.link import BoardClient
from protocol.messages import Heartbeat, NackReason, ServoFrame

pytestmark = pytest.mark.timeout(120)
LAP = 1 << 16


async def _send_heartbeats(c: BoardClient, n: int) -> None:
    """``n`` heartbeats, then an ADVANCE to now whose ACK confirms the board has read them all."""
    for _ in range(n):
        c.send(Heartbeat(0))
    await c.advance(c.board_now_estimate())


def test_nack_for_a_sequence_number_is_forgotten_when_the_number_comes_round(board_factory) -> None:
    board = board_factory("--lockstep")

    async def main() -> None:
        async with await BoardClient.connect(board.port, reconnect=False) as c:
            c.keepalive = False
            now = c.board_now_estimate()
            bad = c.send_frame(ServoFrame(now + 10_000, 1 << 13, (0.0,)))  # servo 14 does not exist
            nack = await c.wait_frame_nack(bad, 5)
            assert nack is not None and nack.reason == NackReason.BAD_VALUE
            assert c.frame_nack(bad) is nack
            # a waiter for the old frame's NACK is answered "none" when its number is reused
            late_waiter = asyncio.ensure_future(c.wait_frame_nack((bad - 1) & 0xFFFF, 60))
            before = c.stats.tx_frames
            while gap := (bad - c.session.tx_seq) & 0xFFFF:  # frames to send before `bad` comes round
                if gap == 1:
                    c.send(Heartbeat(0))
                else:
                    await _send_heartbeats(c, min(gap - 1, 2048))  # + one ADVANCE
            assert await late_waiter is None
            assert c.stats.tx_frames - before == LAP - 1
            now = c.board_now_estimate()
            again = c.send_frame(ServoFrame(now + 10_000, 1, (0.05,)))
            assert again == bad
            assert c.frame_nack(bad) is None  # the bug: the old refusal used to come back here
            await c.advance(now + 60_000)
            tel = await c.wait_for(lambda t: t.last_applied_seq == bad, 10)
            assert tel.board_time_us >= now + 10_000
            assert await c.wait_frame_nack(bad, 0.2) is None
            assert c.stats.frame_nacks == 1

    asyncio.run(main())
