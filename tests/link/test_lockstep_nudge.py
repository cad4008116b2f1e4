"""Waiting for a lockstep board's report never stalls: ``BoardClient.wait_for(..., nudge=True)``.

A lockstep board reports only while its clock runs, and its clock runs only as far as the host
lets it. A wait for "the next report" must therefore ADVANCE it, and again when that report (a
17-frame TELEMETRY on classic CAN) or the ADVANCE itself was lost. Lossy links are real here:
the emulated board injects drops both ways, seeded.
"""

from __future__ import annotations

from pathlib import Path

import anyio
import pytest

from host.link.board_process import start_board
from host.link import BoardClient


@pytest.mark.parametrize(("link", "faults"), [("pty", None), ("can:slcan:pty", "drop=0.05")])
def test_every_wait_for_the_next_report_returns(link: str, faults: str | None, tmp_path: Path) -> None:
    args = ["--lockstep"] + (["--faults", faults, "--fault-seed", "3"] if faults else [])
    board = start_board(args, tmp_path / "board.stderr", link=link)

    async def main() -> list[int]:
        async with await BoardClient.connect(board.spec, handshake_timeout=8.0) as client:
            times: list[int] = []
            for _ in range(10):
                after = client.board_now_estimate()
                tel = await client.wait_for(lambda t, a=after: t.board_time_us > a, timeout=10.0, nudge=True)
                times.append(tel.board_time_us)
            return times

    try:
        times = anyio.run(main, backend="asyncio")
    finally:
        board.stop()
    assert times == sorted(set(times)) and times[0] > 0  # ten reports, each later than the last
    # one nudge moves the board one report period (+ a tick) on: a report never lags far behind
    assert all(b - a <= 10 * 22_000 for a, b in zip(times, times[1:]))
    if faults:
        assert '"drop": 0,' not in (tmp_path / "board.stderr").read_text().split("board: faults ")[-1]


@pytest.mark.parametrize("link", ["pty", "can:slcan:pty"])
def test_a_lockstep_board_says_whether_it_reached_a_time(link: str, tmp_path: Path) -> None:
    """``BoardClient.board_reached``: one TIME_SYNC, whose reply carries the board's own clock, tells a
    board that is already at an ADVANCE target (its report was lost) from one still short of it (slow):
    the silence watchdog moves its target on only in the first case."""
    board = start_board(["--lockstep"], tmp_path / "board.stderr", link=link)

    async def main() -> tuple[bool, bool, int, int]:
        async with await BoardClient.connect(board.spec, handshake_timeout=8.0) as client:
            start = client.board_now_estimate()
            ahead = await client.board_reached(start + 1_000_000, timeout=2.0)  # 1 s ahead: not there
            target = start + client.report_period_us()  # one report period and one tick on
            await client.advance(target)
            tel = await client.wait_for(lambda t: t.board_time_us > start, timeout=10.0)  # that period's report
            there = False
            for _ in range(50):  # the board may still be running its last tick when the first probe comes
                if there := await client.board_reached(target, timeout=2.0):
                    break
            return ahead, there, target, tel.board_time_us

    try:
        ahead, there, target, reported = anyio.run(main, backend="asyncio")
    finally:
        board.stop()
    assert not ahead
    # the last report is short of the target (the board reports on its period; the target is a tick
    # past it), as after a lost report: the board's clock says it is there all the same
    assert reported < target and there
