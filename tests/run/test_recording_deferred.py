"""The recording does its work from the loop, after the link callback that noted it, in order.

A profile of a realtime run showed the MCAP writes inside the link's read callback (forward
kinematics, JSON) as half of that callback, while a token chunk waited behind it. Now the callbacks
only note what happened; the work follows from the loop. Checked here: the callback itself writes
nothing; the work comes in the order noted, nothing dropped; with no running loop it is done at
once; ``close`` does what is still noted. A real ``RunLog`` (no MCAP file: its calls are recorded)
behind the listener seam; the client is the callbacks' lists and counters the recording reads.
"""

from __future__ import annotations

import asyncio
from types import SimpleNamespace
from typing import Any

from host.link.receive import LinkStats
from host.run.mcap_log import RunLog
from host.run.recording import Recording
from protocol.messages import FaultFlags, ServoFrame, SimState, Telemetry
from robots.registry import load_robot


class _Log(RunLog):
    """A RunLog that records what the recording asked of it (and does it)."""

    def __init__(self) -> None:
        super().__init__(load_robot("coco"))
        self.asked: list[tuple[str, Any]] = []

    def on_message(self, msg: Any) -> None:
        self.asked.append(("message", msg.board_time_us))
        super().on_message(msg)

    def on_frame_sent(self, seq: int, msg: Any, board_time_us: int) -> None:
        self.asked.append(("sent", seq))
        super().on_frame_sent(seq, msg, board_time_us)


def _recording() -> tuple[Recording, _Log]:
    client = SimpleNamespace(on_fault=[], on_nack=[], on_sent=[], on_received=[], stats=LinkStats(),
                             board_now_estimate=lambda: 1_000)
    runtime = SimpleNamespace(captures=[], board_times={}, robot=load_robot("coco"))
    shell = SimpleNamespace(last_result=None)
    log = _Log()
    return Recording(log, client, runtime, shell), log  # type: ignore[arg-type]


def _tel(t_us: int) -> Telemetry:
    n = 12
    return Telemetry(t_us, (0.0,) * n, (0.0,) * n, (0.0,) * n, (0.0, 0.0, 0.0), FaultFlags.NONE, 0, 0, 0, 0, 0)


def _sim(t_us: int) -> SimState:
    return SimState(t_us, (0.0, 0.0, 0.3), (1.0, 0.0, 0.0, 0.0))


async def _passes(n: int = 50) -> None:
    """Let the loop come round ``n`` times (the work goes in slices of ``DRAIN_SLICE_S``, one per pass)."""
    for _ in range(n):
        await asyncio.sleep(0)


def test_the_link_callback_only_notes_and_the_loop_does_it_in_order() -> None:
    rec, log = _recording()

    async def main() -> None:
        rec.client.on_received[0](_tel(10_000))
        rec.client.on_sent[0](7, ServoFrame(20_000, 1, (0.1,)))
        rec.client.on_received[0](_sim(10_000))
        rec.client.on_received[0](_tel(30_000))
        assert log.asked == []  # inside the callback: nothing written yet
        await _passes()
        assert log.asked == [("message", 10_000), ("sent", 7), ("message", 10_000), ("message", 30_000)]

    asyncio.run(main())
    rec.close()


def test_without_a_loop_it_is_done_at_once_and_close_does_what_is_left() -> None:
    rec, log = _recording()
    rec.client.on_received[0](_tel(10_000))
    assert log.asked == [("message", 10_000)]

    async def main() -> None:
        rec.client.on_received[0](_tel(20_000))
        rec.close()  # before the loop came round to it
        assert log.asked == [("message", 10_000), ("message", 20_000)]
        assert rec.client.on_received == []

    asyncio.run(main())


def test_past_max_deferred_the_work_is_done_at_once(monkeypatch: Any) -> None:
    """A loop that never comes round (a callback flood) must not let the noted work grow without bound."""
    import host.run.recording as recording

    monkeypatch.setattr(recording, "MAX_DEFERRED", 3)
    rec, log = _recording()

    async def main() -> None:
        for t in (10_000, 20_000):
            rec.client.on_received[0](_tel(t))
        assert log.asked == []
        rec.client.on_received[0](_tel(30_000))  # the third: done now, all three in order
        assert log.asked == [("message", 10_000), ("message", 20_000), ("message", 30_000)]
        await asyncio.sleep(0)
        assert len(log.asked) == 3  # the drain still scheduled finds nothing left

    asyncio.run(main())
    rec.close()


def test_the_loop_does_the_work_in_slices_and_other_callbacks_run_between(monkeypatch: Any) -> None:
    """A slice of 0 s: one noted item per pass of the loop. A callback that became ready meanwhile (a
    token chunk, a frame to send) runs after the first item, not after all of them: the MCAP chunk
    compressed inside one item's ``log()`` took 4-5 ms, and a token waited behind the whole batch."""
    import host.run.recording as recording

    monkeypatch.setattr(recording, "DRAIN_SLICE_S", 0.0)
    rec, log = _recording()

    async def main() -> None:
        for t in (10_000, 20_000, 30_000, 40_000):
            rec.client.on_received[0](_tel(t))
        asyncio.get_running_loop().call_soon(lambda: log.asked.append(("other", 0)))
        await _passes()
        assert log.asked == [("message", 10_000), ("other", 0), ("message", 20_000), ("message", 30_000),
                             ("message", 40_000)]

    asyncio.run(main())
    rec.close()
