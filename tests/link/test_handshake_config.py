"""The handshake's CONFIGs (a slow line's watchdog and report rate, issue 46): sent after CAPS, before
TIME_SYNC; the report rate taken into CAPS; a board that refuses one cannot be used on that line."""

from __future__ import annotations

import asyncio

import pytest

from host.link import BoardClient, HandshakeError
from protocol.messages import ConfigKey

pytestmark = pytest.mark.timeout(60)


def test_the_handshake_sets_the_watchdog_and_the_report_rate(board_factory) -> None:
    board = board_factory("--lockstep")

    async def main() -> None:
        config = ((ConfigKey.WATCHDOG_MS, 1_220), (ConfigKey.TELEMETRY_RATE_HZ, 1))
        async with await BoardClient.connect(board.spec, reconnect=False, link_config=config) as c:
            assert c.caps is not None and c.caps.telemetry_rate_hz == 1
            assert c.report_period_us() == 1_002_000  # what a lockstep top-up reaches past
            tel = await c.wait_for(lambda t: t.board_time_us >= 1_000_000, timeout=10, nudge=True)
            assert tel.board_time_us == 1_000_000  # the first report: 1 Hz
            assert not tel.faults  # a 1-s ADVANCE with no frame in it: the 200 ms watchdog would hold

    asyncio.run(main())


def test_a_board_that_refuses_a_config_the_line_needs_fails_the_handshake(board_factory) -> None:
    board = board_factory("--lockstep")

    async def main() -> None:
        with pytest.raises(HandshakeError, match=r"refused CONFIG WATCHDOG_MS=0 .*which this line needs"):
            await BoardClient.connect(board.spec, reconnect=False, link_config=((ConfigKey.WATCHDOG_MS, 0),))

    asyncio.run(main())
