"""The run's silence watchdog counts only silence it watched (``host.run.pump.silence_watchdog``).

Inside User-Mode Linux on a loaded machine a board took ~12 s to start; the watchdog counted the
silence from when the session's recorder was made, so every such run ended at its first check with
"no telemetry from the board for 10 s". These run the watchdog itself on Trio's virtual clock with a
recorder that heard nothing for 20 s before the watch began.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import anyio
import pytest

from host.link.errors import LinkError
from host.run.pump import TELEMETRY_SILENCE_S, Recorder, silence_watchdog


@dataclass
class _Streamer:
    frames_sent: int = 0
    held: bool = False
    first_free_us: int = 0

    def board_now_us(self) -> int:
        return 0


@dataclass
class _Runtime:  # the two things the watchdog reads of a RobotRuntime
    streamer: _Streamer = field(default_factory=_Streamer)


def _aged_recorder() -> Recorder:
    rec = Recorder()
    rec.last_rx = time.monotonic() - 2 * TELEMETRY_SILENCE_S  # the board took 20 s to start
    return rec


@pytest.fixture
def anyio_backend() -> tuple[str, dict]:
    from trio.testing import MockClock

    return ("trio", {"clock": MockClock(autojump_threshold=0)})


@pytest.mark.anyio
async def test_silence_before_the_watch_began_does_not_count() -> None:
    runtime = _Runtime()
    async with anyio.create_task_group() as tg:  # a LinkError here would fail the test
        tg.start_soon(silence_watchdog, runtime, _aged_recorder())
        for _ in range(20):  # 5 virtual seconds of a host that keeps streaming
            runtime.streamer.frames_sent += 1
            await anyio.sleep(0.25)
        tg.cancel_scope.cancel()


@pytest.mark.anyio
async def test_silence_it_watched_still_ends_the_run() -> None:
    runtime = _Runtime()
    rec = _aged_recorder()
    with pytest.RaisesGroup(pytest.RaisesExc(LinkError, match="no telemetry from the board")):
        async with anyio.create_task_group() as tg:
            tg.start_soon(silence_watchdog, runtime, rec)
            await anyio.sleep(0.5)
            rec.last_rx = time.monotonic() - 2 * TELEMETRY_SILENCE_S  # then the board fell silent for 20 s
            for _ in range(20):
                runtime.streamer.frames_sent += 1
                await anyio.sleep(0.25)


@dataclass
class _Stats:
    decode_errors: int = 0
    retries: int = 1  # a request was re-sent (its ACK was slow or lost): the link counts as lossy


@dataclass
class _LockstepClient:  # what the watchdog reads of a lockstep BoardClient, and the ADVANCEs it sends
    seen_us: int = 20_000  # the board time of the latest report the host has
    board_us: int = 20_000  # where the board's clock really is (what a TIME_SYNC reply would say)
    lockstep: bool = True
    stats: _Stats = field(default_factory=_Stats)
    targets: list[int] = field(default_factory=list)
    probes: int = 0

    def board_now_estimate(self) -> int:
        return self.seen_us

    def report_period_us(self) -> int:
        return 22_000

    async def board_reached(self, t_us: int, timeout: float) -> bool:
        self.probes += 1
        return self.seen_us >= t_us or self.board_us >= t_us

    async def advance(self, until_us: int) -> None:
        self.targets.append(until_us)


@dataclass
class _SentStreamer(_Streamer):
    next_us: int = 90_000  # frames sent up to 80 ms (one 10-ms period before the next)
    period_us: int = 10_000


@pytest.mark.anyio
async def test_a_lockstep_nudge_moves_its_target_on_only_once_the_board_is_there() -> None:
    """A QEMU board starved for over a second on a loaded CI machine: a FLUSH was re-sent (the link
    counts as lossy, nudges every 50 ms), the streamer waited for its ACK, and each nudge ADVANCEd the
    board one report period further; the frames sent after the ACK arrived LATE (2 NACKs). Now the
    target stays one period past the frames sent while the board is behind it, however long that
    lasts, and moves on once a report reached it or the board says it is there (its report was lost)."""
    runtime = _Runtime(streamer=_SentStreamer())
    client = _LockstepClient()
    rec = Recorder()
    rec.last_rx = anyio.current_time()  # the last report came just now; none follows
    async with anyio.create_task_group() as tg:
        tg.start_soon(silence_watchdog, runtime, rec, client, anyio.current_time)
        await anyio.sleep(3.0)  # a slow board: no report, and its clock still short of the target, for 3 s
        assert len(client.targets) >= 30 and set(client.targets) == {102_000}, client.targets  # 80 + 22 ms, repeated
        assert client.probes >= 30  # it asked every time
        client.board_us = 102_000  # the board got there, and that report was lost: one period further
        n = len(client.targets)
        await anyio.sleep(0.2)
        assert client.targets[n] == 124_000 and set(client.targets[n:]) == {124_000}, client.targets[n:]
        client.seen_us = 124_000  # a report reached the target (and none since): the next nudge moves on
        n = len(client.targets)
        await anyio.sleep(0.1)
        assert client.targets[n] == 146_000, client.targets[n:]
        tg.cancel_scope.cancel()
