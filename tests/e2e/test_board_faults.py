"""Board faults seen from the host, on a real lockstep board subprocess on a pty.

* a WATCHDOG_FAULT latched after the previous host went away is cleared at connect and the run works;
* a board in ESTOP is refused at once with a message naming ``ghostshell estop --clear``;
* an ESTOP raised mid-run fails the running call and the turn (never "done", never a hang);
* ``ghostshell estop`` sends ESTOP and, with ``--clear``, ESTOP_CLEAR.

The watchdog is made to fire by turning the client's keep-alive off and advancing the lockstep
board past hold + crouch (200 ms + 1 s): board time, not wall time, so no sleeps.
"""

from __future__ import annotations

import asyncio
import logging
import subprocess
import sys
from pathlib import Path

import anyio
import pytest

from host.link import BoardClient, BoardFaulted
from host.link.board_process import start_board
from host.run.runner import RunOptions, run_program
from host.run.robot_session import RobotSession, SessionOptions
from protocol.messages import FaultFlags

pytestmark = pytest.mark.timeout(120)


async def _leave_watchdog_fault(port: str) -> None:
    """Be a host that goes away: stop feeding the watchdog and let the board latch WATCHDOG_FAULT."""
    async with await BoardClient.connect(port, reconnect=False) as c:
        c.keepalive = False
        await c.advance(c.board_now_estimate() + 2_000_000)
        tel = await c.wait_for(lambda t: bool(t.faults & FaultFlags.WATCHDOG_FAULT), 10)
        assert not tel.faults & FaultFlags.ESTOP


async def _faults(port: str) -> FaultFlags:
    async with await BoardClient.connect(port, reconnect=False) as c:
        at = c.board_now_estimate()
        await c.advance(at + 20_000)
        tel = await c.wait_for(lambda t: t.board_time_us > at, 10)
        return FaultFlags(tel.faults & (FaultFlags.ESTOP | FaultFlags.WATCHDOG_FAULT))


def test_leftover_watchdog_fault_is_cleared_and_the_run_works(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    board = start_board(["--lockstep"], tmp_path / "board.stderr")
    try:
        asyncio.run(_leave_watchdog_fault(board.port))
        opts = RunOptions(program="<push_up/>", out=tmp_path / "run", lockstep=True, link=board.port)
        with caplog.at_level(logging.WARNING, logger="host.run"):
            report = anyio.run(run_program, opts, backend="asyncio")
    finally:
        board.stop()
    assert any("cleared the board's latched WATCHDOG_FAULT" in r.getMessage() for r in caplog.records)
    assert report.summary.outcome == "done"
    assert [(c.function, c.outcome) for c in report.calls] == [("push_up", "done")]
    assert report.summary.extra["link"]["frame_nacks"] == 0


def test_estopped_board_is_refused_with_how_to_clear_it(tmp_path: Path) -> None:
    board = start_board(["--lockstep"], tmp_path / "board.stderr")
    try:
        async def estop() -> None:
            async with await BoardClient.connect(board.port, reconnect=False) as c:
                await c.estop()

        asyncio.run(estop())
        opts = RunOptions(program="<push_up/>", out=tmp_path / "run", lockstep=True, link=board.port)
        with pytest.raises(BoardFaulted, match=r"ESTOP.*ghostshell estop --link \S+ --clear"):
            anyio.run(run_program, opts, backend="asyncio")
        # the CLI: one clear message, nonzero exit, and the estop is still there (never cleared for the user)
        cli = subprocess.run([sys.executable, "-m", "host", "run", "--task", "2", "--lockstep", "--no-live",
                              "--link", board.port, "--out", str(tmp_path / "cli")],
                             capture_output=True, text=True, timeout=60)
        assert cli.returncode == 1, cli.stdout + cli.stderr
        assert "is in ESTOP" in cli.stderr and "--clear" in cli.stderr
        assert asyncio.run(_faults(board.port)) & FaultFlags.ESTOP
    finally:
        board.stop()


def test_estop_mid_run_fails_the_call_and_the_turn(tmp_path: Path) -> None:
    board = start_board(["--lockstep"], tmp_path / "board.stderr")

    async def main() -> object:
        opts = SessionOptions(out=tmp_path / "run", lockstep=True, link=board.port)
        async with RobotSession(opts) as s:
            streamer, client = s.runtime.streamer, s.client
            assert client is not None
            t0 = streamer.board_now_us()

            async def press_estop() -> None:  # someone presses the e-stop 0.3 board seconds into the push-up
                await streamer.wait_board_time(t0 + 300_000)
                await client.estop()

            async with anyio.create_task_group() as tg:
                tg.start_soon(press_estop)
                turn = await s.run_turn("<push_up/>")
            again = await s.run_turn("<push_up/>", write=False)  # still in ESTOP: fails at once too
            return turn, again

    try:
        turn, again = anyio.run(main, backend="asyncio")  # type: ignore[misc]
    finally:
        board.stop()
    for t in (turn, again):
        assert t.summary.outcome == "failed"
        assert [(c.function, c.outcome) for c in t.calls] == [("push_up", "failed")]
        assert "ESTOP" in t.summary.extra["board_fault"] and "--clear" in t.summary.extra["board_fault"]
        assert "ESTOP" in (t.calls[0].error or "")


def test_estop_command_both_ways(tmp_path: Path) -> None:
    board = start_board(["--lockstep"], tmp_path / "board.stderr")
    try:
        def estop(*extra: str) -> subprocess.CompletedProcess[str]:
            return subprocess.run([sys.executable, "-m", "host", "estop", "--link", board.port, *extra],
                                  capture_output=True, text=True, timeout=60)

        on = estop()
        assert on.returncode == 0 and "ESTOP acknowledged" in on.stdout, on.stderr
        assert asyncio.run(_faults(board.port)) & FaultFlags.ESTOP
        off = estop("--clear")
        assert off.returncode == 0 and "ESTOP_CLEAR acknowledged" in off.stdout, off.stderr
        assert not asyncio.run(_faults(board.port)) & FaultFlags.ESTOP
        bad = subprocess.run([sys.executable, "-m", "host", "estop", "--link", "pty"],
                             capture_output=True, text=True, timeout=60)
        assert bad.returncode == 2 and "running board" in bad.stderr
    finally:
        board.stop()
