"""Every wait of a session's work ends, by telemetry or by a deadline (issue 41).

The hang class: a wait that sees neither telemetry nor a deadline. A lockstep board held still while the
host waits for an LLM chunk that never comes is the plainest one: the silence watchdog exempts a held
board (silent on purpose), the board-time bound never comes (board time stands still), so before the
no-progress guard the turn waited for ever. And a stop whose graceful end cannot run (an interrupted
motion's stop waiting for a frame lock that is never released) took the stop's own 12-s timeout,
longer than a first Ctrl-C should take; the stop's deadline (``stop_grace_s``) now cuts it.

Real lockstep board, real pty; ``anyio.fail_after`` turns a regression into a failure, not a hang.
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path

import anyio

from host.run.robot_session import RobotSession, SessionOptions, TurnResult
from host.run.stops import StopReason


async def _an_llm_that_never_answers() -> AsyncIterator[str]:
    await anyio.Event().wait()
    yield ""  # never reached


def test_a_held_board_waiting_for_an_llm_that_never_answers_ends_stalled(tmp_path: Path) -> None:
    async def main() -> TurnResult:
        with anyio.fail_after(60):
            async with RobotSession(SessionOptions(out=tmp_path, lockstep=True, mcap=False, plots=False,
                                                   progress_limit_s=1.5)) as s:
                return await s.run_turn(_an_llm_that_never_answers(), hold=True, settle_s=0.1)

    turn = anyio.run(main, backend="asyncio")
    s = turn.summary
    assert s.outcome == "stalled", s.extra
    assert s.extra["stopped"]["by"] == "no_progress" and s.extra["stopped"]["kind"] == "stall"
    message = s.extra["stopped"]["message"]
    assert message.startswith("no progress for ") and "while running the turn" in message
    assert "the LLM's next chunk" in message
    assert (turn.out / "summary.json").exists()


def test_the_stop_deadline_cuts_a_turn_whose_stop_cannot_run(tmp_path: Path) -> None:
    """The motion's stop waits for the streamer's frame lock, held by a task that never lets go (a cut
    waiting for an ACK that never comes): its own shielded timeout is 12 s; the stop's deadline (1 s
    here) aborts it and cuts the turn, whose calls are reported as far as they got."""
    cut_after: list[float] = []

    async def main() -> TurnResult:
        with anyio.fail_after(60):
            async with RobotSession(SessionOptions(out=tmp_path, lockstep=True, mcap=False, plots=False,
                                                   stop_grace_s=1.0)) as s:
                streamer = s.runtime.streamer
                release, ended = anyio.Event(), anyio.Event()

                async def stuck_holder(*, task_status: anyio.abc.TaskStatus[None] = anyio.TASK_STATUS_IGNORED) -> None:
                    async with streamer._lock:  # e.g. a cut waiting for an ACK that never comes
                        task_status.started()
                        await release.wait()

                async def stop_while_moving(t0_us: int) -> None:
                    await streamer.wait_board_time(t0_us + 500_000)  # the strides are under way
                    assert any(r.start is not None and r.end is None for r in s.shell.timeline)
                    await tg.start(stuck_holder)
                    s.request_stop(StopReason("limit", "test", "stopped by the test"))
                    t = anyio.current_time()
                    await ended.wait()
                    cut_after.append(anyio.current_time() - t)

                async with anyio.create_task_group() as tg:
                    tg.start_soon(stop_while_moving, streamer.board_now_us())
                    turn = await s.run_turn('<move_strides direction="forward" times="6"/>', settle_s=0.5)
                    ended.set()
                    release.set()
                return turn

    turn = anyio.run(main, backend="asyncio")
    assert turn.summary.outcome == "limit", turn.result.timeline.table()
    assert turn.summary.extra["timing"]["stop_overdue"] is True
    rec = turn.result.timeline.one("move_strides")
    assert rec.outcome != "done"
    assert cut_after and cut_after[0] < 6.0  # the deadline (1 s) and the cut, not the stop's own 12 s


def test_a_cleared_stop_no_longer_cuts_later_turns(tmp_path: Path) -> None:
    """An MCP server clears a bound's stop and runs the next program: the old stop's deadline must not
    cut it (nor a later stop's start it at once)."""
    took: list[float] = []

    async def main() -> TurnResult:
        with anyio.fail_after(60):
            async with RobotSession(SessionOptions(out=tmp_path, lockstep=True, mcap=False, plots=False,
                                                   stop_grace_s=0.05)) as s:
                s.request_stop(StopReason("limit", "max_board_s", "the test's bound"))
                s.clear_stop()
                t = anyio.current_time()
                await anyio.sleep(0.1)  # the wall time under test: the old stop's deadline (0.05 s) passes
                turn = await s.run_turn('<move_strides direction="forward" times="2"/>', settle_s=0.1)
                took.append(anyio.current_time() - t)
                assert not s.stop_overdue
                return turn

    turn = anyio.run(main, backend="asyncio")
    assert took[0] > 0.05  # the turn ended after the old deadline (and was not cut by it)
    assert turn.summary.outcome == "done", turn.result.timeline.table()
    assert turn.summary.extra["timing"]["stop_overdue"] is False
