"""A turn's end path ends even when what it waits for never comes (issue 17, the task-12 hang).

Seen under load (``bench/bench_latency.py --robot arm --tasks 12`` realtime): after the calls were
done the host stopped streaming, only TIME_SYNC went on, no summary was written, and neither the
board-time bound nor the silence watchdog ended the run. Two waits of the end path had no deadline:

* the settle after the turn (``runtime.sleep(settle_s)``): it runs after the turn's board-time bound
  was cancelled, and the silence watchdog does not count a held lockstep board as silent;
* an interrupted motion's shielded stop (``RobotRuntime._motion`` -> ``_stop`` -> ``streamer.cut``),
  which waits for the streamer's frame lock and the FLUSH's ACK while the call is being cancelled.

Each test builds the condition that never becomes true on a real lockstep board (a held board whose
clock cannot reach the settle time; a frame lock that is never released) and asserts the turn now
ends with a clear outcome. ``anyio.fail_after`` turns a regression into a failure instead of a hang.
"""

from __future__ import annotations

from pathlib import Path

import anyio
import pytest

import host.runtime.robot_runtime as runtime_mod
import host.run.robot_session as session_mod
from host.run.robot_session import RobotSession, SessionOptions, TurnResult


def _session(tmp_path: Path) -> RobotSession:
    return RobotSession(SessionOptions(out=tmp_path, lockstep=True, mcap=False))


def test_settle_on_a_board_that_never_gets_there_ends_the_turn(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(session_mod, "TELEMETRY_SILENCE_S", 1.0)  # the settle's wall deadline: 0.5 + 1 s

    async def main() -> TurnResult:
        with anyio.fail_after(40):
            async with _session(tmp_path) as s:
                async with s.runtime.streamer.hold():  # the lockstep board stands still: 0.5 s never comes
                    return await s.run_turn("", settle_s=0.5)

    turn = anyio.run(main, backend="asyncio")
    assert turn.summary.outcome == "done", turn.result.timeline.table()
    assert "settle cut" in turn.summary.extra["settle"]
    assert any("settle cut" in o.message for o in turn.result.observations)
    assert (turn.out / "summary.json").exists()


def test_interrupted_motion_whose_stop_cannot_run_ends_the_turn(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(runtime_mod, "STOP_TIMEOUT_S", 1.0)
    monkeypatch.setattr(session_mod, "TELEMETRY_SILENCE_S", 1.0)

    async def main() -> TurnResult:
        with anyio.fail_after(40):
            async with _session(tmp_path) as s:
                streamer = s.runtime.streamer
                release = anyio.Event()

                async def stuck_holder() -> None:  # e.g. a cut waiting for an ACK that never comes
                    async with streamer._lock:
                        await release.wait()

                async def stop_once_moving() -> None:
                    while not s.shell.running or not any(r.start is not None for r in s.shell.timeline):
                        await anyio.sleep(0.01)
                    tg.start_soon(stuck_holder)
                    await anyio.sleep(0.05)
                    s.request_stop(session_mod.StopReason("limit", "test", "stopped by the test"))

                async with anyio.create_task_group() as tg:
                    tg.start_soon(stop_once_moving)
                    turn = await s.run_turn('<move_strides direction="forward" times="6"/>', settle_s=0.5)
                    release.set()
                s.clear_stop()
                return turn

    turn = anyio.run(main, backend="asyncio")
    assert turn.summary.outcome == "limit", turn.result.timeline.table()  # the stop's kind
    rec = turn.result.timeline.one("move_strides")
    assert rec.outcome != "done"
    assert "settle" not in turn.summary.extra  # a stopped turn does not settle: the rest pose comes next


def test_a_link_task_that_outlives_its_cancel_does_not_hang_the_session_close(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The hang itself: the client's close cancelled its tasks once and waited; Python 3.11's
    ``asyncio.wait_for`` drops a cancel that arrives with the TIME_SYNC reply, so the sync loop ran on
    (TIME_SYNC kept going, nothing else) and the close never returned. The link's loops now run under
    an anyio cancel scope, which cancels again at every await, so one dropped cancel no longer matters;
    here the sync loop ignores every cancel for 3 s (longer than CLOSE_TIMEOUT_S), and the session's
    close is cut after CLOSE_TIMEOUT_S instead of waiting for it."""
    import asyncio
    import time

    from host.link.supervisor import Supervisor

    async def sync_loop_ignoring_cancels(self: Supervisor) -> None:
        deaf_until: float | None = None
        while True:
            try:
                await asyncio.sleep(0.05)
            except asyncio.CancelledError:
                deaf_until = deaf_until or time.monotonic() + 3.0
                if time.monotonic() >= deaf_until:
                    raise  # ends by itself after 3 s, so the event loop can finish after the test

    monkeypatch.setattr(Supervisor, "sync_loop", sync_loop_ignoring_cancels)
    monkeypatch.setattr(session_mod, "CLOSE_TIMEOUT_S", 1.0)

    async def main() -> tuple[TurnResult, RobotSession]:
        with anyio.fail_after(40):
            s = _session(tmp_path)
            async with s:
                turn = await s.run_turn('<head_act action="nod"/>', settle_s=0.1)
            return turn, s

    turn, s = anyio.run(main, backend="asyncio")
    assert turn.summary.outcome == "done"
    assert s.close_timed_out
