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
