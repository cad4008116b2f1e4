"""A realtime SLCAN run whose board stops reading (stopped with SIGSTOP mid-run) ends with one
LinkError instead of hanging.

python-can's ``slcanBus.send`` used to spin in pyserial's write once the pty was full, freezing
the host's event loop, so neither the silence watchdog ("no telemetry from the board for 10 s")
nor the transmit-queue bound could end the run: it hung. The run now ends on its own condition
(no sleeps); the ``thread`` timeout turns a regression into a failure instead of a hung suite.
"""

from __future__ import annotations

import os
import signal
from pathlib import Path

import anyio
import pytest

from host.link.errors import LinkError
from host.run.robot_session import RobotSession, SessionOptions
from support.realtime_lock import realtime_part_done

pytestmark = [pytest.mark.timeout(120, method="thread"), pytest.mark.realtime]


def test_a_board_that_stops_reading_ends_the_run(tmp_path: Path) -> None:
    session = RobotSession(SessionOptions(link="can:slcan:pty", lockstep=False, out=tmp_path))

    async def main() -> None:
        async with session:
            board = session.board
            assert board is not None
            os.kill(board.proc.pid, signal.SIGSTOP)  # the board neither reads nor reports any more
            # nothing runs on the wall clock now (a stopped board has no ticks to miss): the rest, up to
            # 10 s until the host gives up on the silence, need not keep the other workers idle
            realtime_part_done()
            try:
                await session.run_turn('<move_strides direction="forward" times="20"/>', write=False)
            finally:
                os.kill(board.proc.pid, signal.SIGCONT)  # let it stop normally when the session ends

    with pytest.raises(LinkError, match="no telemetry from the board|not draining") as e:
        anyio.run(main, backend="asyncio")
    assert "\n" not in str(e.value)
    turn = session.ended_turn(e.value)
    assert turn is not None and turn.summary.outcome == "link_lost"
    (walk,) = turn.calls
    assert walk.outcome in ("failed", "cancelled") and walk.error is not None
    assert str(e.value) in walk.error or "link lost" in walk.error
