"""The one telemetry driver (``host.motion.driver.drive``): in lockstep, the frames that move board time
past a report go out only after everything the report woke has reacted, however long that takes.

A task waiting on board time is woken by a report and then waits on something else (a thread or wall
time in a busy section; the board's answer to a request: here an event the test sets) before it starts a
motion. Its motion must be in the frames the
report's top-up sends, as if the host had reacted at once. Runs on asyncio (``settle`` looks at its
ready queue) with a recording link: no board, no wall-clock sleeps.
"""

from __future__ import annotations

import anyio
import anyio.lowlevel
import numpy as np

from host.motion.driver import drive
from host.motion.mixer import Mixer
from host.motion.streamer import FrameStreamer
from protocol.messages import ServoFrame, Telemetry
from tests.support.frame_link import RecordingLink, Ramp


def _report(t_us: int, seq: int = 0) -> Telemetry:
    z = (0.0, 0.0)
    return Telemetry(board_time_us=t_us, positions=z, velocities=z, efforts=z, imu_rpy=(0.0, 0.0, 0.0), faults=0,
                     buffer_fill=0, last_applied_seq=seq, late_count=0, dropped_count=0, link_errors=0)


def _frames(link: RecordingLink) -> list[ServoFrame]:
    return [m for m in link.sent if isinstance(m, ServoFrame)]


async def _scenario(mark: str) -> tuple[list[ServoFrame], int]:
    """Reports at 20 and 40 ms; a task waits for board time 20 ms, then for the test's go-ahead inside
    ``mark`` ("busy": a busy section; "reply": as a request awaiting the board's answer; "none": no wait),
    then starts a ramp. Returns the frames sent and the ramp's start."""
    link = RecordingLink(now_us=0, lockstep=True)
    streamer = FrameStreamer(link, Mixer(np.zeros(2)), start_us=0)
    await streamer.top_up(0)  # the first lookahead: frames up to 60 ms
    go = anyio.Event()
    started: list[int] = []
    sent_before_go: list[int] = []
    pending: list[int] = []  # requests awaiting the board's answer
    reports = [_report(20_000), _report(40_000)]

    async def reaction() -> None:
        await streamer.wait_board_time(20_000)
        if mark == "busy":
            async with streamer.busy():
                await go.wait()
        elif mark == "reply":
            pending.append(1)
            await go.wait()
            pending.clear()
        seg = streamer.add(Ramp(), label="ramp")
        started.append(seg.start_us)

    async def feed():  # type: ignore[no-untyped-def]
        for r in reports:
            yield r

    def on_report(tel: Telemetry) -> bool:
        if tel.board_time_us == 20_000 and mark != "none":
            tg.start_soon(release)
        return False

    polls: list[int] = []  # the driver's looks at the pending requests

    def pending_replies() -> int:
        polls.append(len(pending))
        return len(pending)

    async def release() -> None:
        # the reaction is blocked: nothing beyond the first lookahead may have gone out
        if mark == "reply":  # the driver polls the requests (a timer): wait until it saw this one 3 times
            with anyio.fail_after(10):  # a driver that never asks fails here instead of hanging
                while polls.count(1) < 3:
                    await anyio.lowlevel.checkpoint()
        else:  # the driver waits for the busy section to end
            await anyio.wait_all_tasks_blocked()
        sent_before_go.append(len(_frames(link)))
        go.set()

    async with anyio.create_task_group() as tg:
        tg.start_soon(reaction)
        await anyio.lowlevel.checkpoint()
        await drive(streamer, feed(), lockstep=True, on_report=on_report, pending_replies=pending_replies)
    if mark != "none":
        assert sent_before_go == [6], sent_before_go  # 10..60 ms: the reaction's wait held the top-up back
    return _frames(link), started[0]


def _run(mark: str) -> tuple[list[ServoFrame], int]:
    return anyio.run(_scenario, mark, backend="asyncio")


def test_a_reaction_that_waits_is_in_the_frames_of_its_report() -> None:
    quick, quick_start = _run("none")
    for mark in ("busy", "reply"):
        slow, slow_start = _run(mark)
        assert slow_start == quick_start == 70_000  # the first unsent frame after the first lookahead
        assert slow == quick, mark  # the same frames, the ramp in the same ones
    assert any(f.targets[0] > 0 for f in quick)  # the ramp did reach the frames
