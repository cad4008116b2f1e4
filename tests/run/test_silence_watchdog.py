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
from host.run.pump import LOCKSTEP_LOST_S, TELEMETRY_SILENCE_S, Recorder, silence_watchdog


@dataclass
class _Streamer:
    frames_sent: int = 0
    held: bool = False
    reacting: bool = False  # held, or a busy section under way
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
class _Requests:
    pending: dict[int, object] = field(default_factory=dict)  # requests awaiting the board's answer


@dataclass
class _LockstepClient:  # what the watchdog reads of a lockstep BoardClient, and the ADVANCEs it sends
    seen_us: int = 20_000  # the board time of the latest report the host has
    board_us: int = 20_000  # where the board's clock really is (what a TIME_SYNC reply would say)
    lockstep: bool = True
    stats: _Stats = field(default_factory=_Stats)
    targets: list[int] = field(default_factory=list)
    probes: int = 0
    requests: _Requests = field(default_factory=lambda: _Requests())

    def link_lossy(self) -> bool:
        return self.stats.decode_errors > 0 or self.stats.retries > 0

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
    top_ups: list[int] = field(default_factory=list)

    async def top_up(self, board_now_us: int | None = None) -> None:
        assert board_now_us is not None
        self.top_ups.append(board_now_us)
        self.next_us = board_now_us + 60_000 + self.period_us  # one lookahead of frames from there
        self.frames_sent += 6


@pytest.mark.anyio
async def test_a_lossy_lockstep_recovery_never_runs_the_board_past_the_frames_sent() -> None:
    """A QEMU board starved for over a second on a loaded CI machine: a FLUSH was re-sent (the link
    counts as lossy, recoveries every 50 ms). Before, each nudge ADVANCEd the board a report period past
    the frames sent, and the frames sent next arrived LATE. Now, while the board is short of the last
    frame sent, it is only let run to there (lost frames or not); once it is there (its reports were
    lost), the host sends the next lookahead of frames from there instead of an ADVANCE past them."""
    runtime = _Runtime(streamer=_SentStreamer())
    client = _LockstepClient()
    rec = Recorder()
    rec.last_rx = anyio.current_time()  # the last report came just now; none follows
    async with anyio.create_task_group() as tg:
        tg.start_soon(silence_watchdog, runtime, rec, client, anyio.current_time)
        await anyio.sleep(3.0)  # a slow board: no report, and its clock short of the last frame, for 3 s
        assert len(client.targets) >= 30 and set(client.targets) == {80_001}, client.targets  # the last frame's tick
        assert client.probes >= 30 and runtime.streamer.top_ups == []  # it asked every time
        client.board_us = 80_000  # the board got there, and its report was lost: frames from there
        n = len(client.targets)
        await anyio.sleep(0.1)
        assert runtime.streamer.top_ups[:1] == [80_000], runtime.streamer.top_ups
        last_sent = runtime.streamer.next_us - runtime.streamer.period_us
        assert all(t <= last_sent + 1 for t in client.targets[n:]), (client.targets[n:], last_sent)
        tg.cancel_scope.cancel()


@pytest.mark.anyio
async def test_a_healthy_lockstep_link_sends_nothing_on_wall_time() -> None:
    """A link that lost nothing: a host stalled on its own work, or a slow board, is no reason to send the
    board anything (the message stream of a lockstep run is a function of its input). Only after
    ``LOCKSTEP_LOST_S`` of silence is a loss assumed all the same."""
    runtime = _Runtime(streamer=_SentStreamer())
    client = _LockstepClient(stats=_Stats(retries=0))
    rec = Recorder()
    rec.last_rx = anyio.current_time()
    async with anyio.create_task_group() as tg:
        tg.start_soon(silence_watchdog, runtime, rec, client, anyio.current_time)
        await anyio.sleep(LOCKSTEP_LOST_S - 0.1)
        assert client.targets == [] and client.probes == 0 and runtime.streamer.top_ups == []
        await anyio.sleep(0.2)
        assert client.targets == [80_001] and client.probes == 1
        tg.cancel_scope.cancel()


@pytest.mark.anyio
async def test_a_lockstep_board_answering_a_request_is_not_silent() -> None:
    """The telemetry driver waits for the board's answers to requests before it tops up (the reaction to
    a report includes them): the board's silence meanwhile is on purpose, however long, and no
    recovery goes out during it; once answered, silence counts again."""
    runtime = _Runtime(streamer=_SentStreamer())
    client = _LockstepClient(stats=_Stats(retries=0))
    client.requests.pending[7] = object()  # e.g. a camera capture over a slow line
    rec = Recorder()
    rec.last_rx = anyio.current_time()
    async with anyio.create_task_group() as tg:
        tg.start_soon(silence_watchdog, runtime, rec, client, anyio.current_time)
        await anyio.sleep(TELEMETRY_SILENCE_S + 1)  # longer than the run's silence limit
        assert client.targets == [] and client.probes == 0
        client.requests.pending.clear()
        await anyio.sleep(LOCKSTEP_LOST_S + 0.1)
        assert client.targets == [80_001]
        tg.cancel_scope.cancel()


@pytest.mark.anyio
async def test_a_host_reacting_to_a_report_is_not_a_silent_board() -> None:
    """The pump handling a report (``rec.waiting`` False: a stalled dispatch, a slow top-up) is the
    host's own time: no recovery goes out during it, however long; once the pump waits again, silence
    counts from then. A disturbed lockstep run had its silence watchdog probe the board mid-run (a
    TIME_SYNC in the board's stream) while the pump stood in an injected 1-s stall."""
    runtime = _Runtime(streamer=_SentStreamer())
    client = _LockstepClient(stats=_Stats(retries=0))
    rec = Recorder()
    rec.last_rx, rec.waiting = anyio.current_time(), False
    async with anyio.create_task_group() as tg:
        tg.start_soon(silence_watchdog, runtime, rec, client, anyio.current_time)
        await anyio.sleep(3 * LOCKSTEP_LOST_S)
        assert client.targets == [] and client.probes == 0
        rec.waiting = True
        await anyio.sleep(LOCKSTEP_LOST_S - 0.1)
        assert client.probes == 0
        await anyio.sleep(0.2)
        assert client.probes == 1
        tg.cancel_scope.cancel()
