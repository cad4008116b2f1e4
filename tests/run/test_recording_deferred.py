"""The recording's work runs on its writer thread, in the order the link's callbacks handed it over.

The scene of an arm with meshes built on the event loop tripped the board's 200 ms watchdog; the MCAP
writes inside the link's read callback were half of that callback. Now the callbacks only hand the
messages over (a bounded queue); one thread does every RunLog call. Checked here: nothing is written on
the callback's thread; the order is the order handed over; a full queue drops and counts, never blocks;
``close`` finishes the file on the thread and waits a bounded time. A real ``RunLog`` writing a real
MCAP behind the listener seam; the client is the callbacks' lists and counters the recording reads.
Synchronisation: :meth:`LogWriter.wait_idle` and ``threading.Event`` (no sleeps).
"""

from __future__ import annotations

import asyncio
import threading
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from host.link.receive import LinkStats
from host.run.log_writer import LogWriter
from host.run.mcap_log import RunLog
from host.run.mcap_read import McapRun
from host.run.recording import Recording
from protocol.messages import FaultFlags, ServoFrame, SimState, Telemetry
from robots.registry import load_robot


class _Log(RunLog):
    """A RunLog that records what the recording asked of it, and on which thread (and does it)."""

    def __init__(self) -> None:
        super().__init__(load_robot("coco"))
        self.asked: list[tuple[str, Any]] = []
        self.threads: set[int] = set()

    def on_message(self, msg: Any) -> None:
        self.threads.add(threading.get_ident())
        self.asked.append(("message", msg.board_time_us))
        super().on_message(msg)

    def on_frame_sent(self, seq: int, msg: Any, board_time_us: int) -> None:
        self.threads.add(threading.get_ident())
        self.asked.append(("sent", seq))
        super().on_frame_sent(seq, msg, board_time_us)


def _recording(tmp_path: Path) -> tuple[Recording, _Log]:
    client = SimpleNamespace(on_fault=[], on_nack=[], on_sent=[], on_received=[], stats=LinkStats(),
                             board_now_estimate=lambda: 1_000)
    runtime = SimpleNamespace(captures=[], board_times={}, robot=load_robot("coco"))
    shell = SimpleNamespace(last_result=None)
    log = _Log()
    log.open(tmp_path / "run.mcap")
    return Recording(log, client, runtime, shell), log  # type: ignore[arg-type]


def _tel(t_us: int) -> Telemetry:
    n = 12
    return Telemetry(t_us, (0.0,) * n, (0.0,) * n, (0.0,) * n, (0.0, 0.0, 0.0), FaultFlags.NONE, 0, 0, 0, 0, 0)


def _sim(t_us: int) -> SimState:
    return SimState(t_us, (0.0, 0.0, 0.3), (1.0, 0.0, 0.0, 0.0))


def test_the_callbacks_hand_over_and_the_writer_thread_logs_in_order(tmp_path: Path) -> None:
    rec, log = _recording(tmp_path)
    gate = threading.Event()
    rec.writer.submit(gate.wait)  # the thread waits here: whatever follows is only queued

    async def main() -> None:
        rec.client.on_received[0](_tel(10_000))
        rec.client.on_sent[0](7, ServoFrame(20_000, 1, (0.1,)))
        rec.client.on_received[0](_sim(10_000))
        rec.client.on_received[0](_tel(30_000))
        for _ in range(20):  # the loop's own bookkeeping (slices) runs; it writes nothing
            await asyncio.sleep(0)
        assert log.asked == []

    asyncio.run(main())
    gate.set()
    assert rec.writer.wait_idle(30)
    assert log.asked == [("message", 10_000), ("sent", 7), ("message", 10_000), ("message", 30_000)]
    assert log.threads == {rec.writer._thread.ident} and threading.get_ident() not in log.threads
    rec.close()
    assert rec.client.on_received == [] and rec.dropped == 0
    counts = McapRun(tmp_path / "run.mcap").counts()
    assert counts["/joint_states"] == 2 and counts["/link/tx"] == 1 and counts["/scene"] == 1


def test_a_full_queue_drops_and_counts_and_never_blocks_the_caller() -> None:
    w = LogWriter(max_queued=5).start()
    started, gate = threading.Event(), threading.Event()
    got: list[int] = []
    assert w.submit(lambda: (started.set(), gate.wait()))
    assert started.wait(30)  # the thread is inside that call: the queue is empty and stays unserved
    accepted = [w.submit(got.append, i) for i in range(8)]
    assert accepted == [True] * 5 + [False] * 3
    assert w.dropped == 3 and w.waiting() == 6 and w.max_waiting == 6
    gate.set()
    assert w.close(30)
    assert got == [0, 1, 2, 3, 4]  # FIFO, nothing reordered
    assert w.submit(got.append, 99) is False and w.dropped == 4  # closed: dropped too


def test_close_waits_a_bounded_time_for_a_stuck_thread() -> None:
    w = LogWriter().start()
    gate = threading.Event()
    w.submit(gate.wait)
    assert w.close(0.01) is False  # the thread is stuck: close returns after its timeout
    gate.set()
    assert w.close(30) is True


def test_a_call_that_raises_is_counted_and_the_thread_goes_on() -> None:
    w = LogWriter().start()
    got: list[int] = []
    w.submit(lambda: 1 / 0)
    w.submit(got.append, 1)
    assert w.close(30)
    assert got == [1] and w.errors == 1 and isinstance(w.first_error, ZeroDivisionError)


def test_a_failing_run_log_is_one_note_and_the_run_goes_on(tmp_path: Path) -> None:
    rec, log = _recording(tmp_path)

    def broken(msg: Any) -> None:
        raise RuntimeError("sink gone")

    log.on_message = broken  # type: ignore[method-assign]
    rec.client.on_received[0](_tel(10_000))
    rec.client.on_received[0](_tel(20_000))
    assert rec.writer.wait_idle(30)
    rec.close()
    assert rec.notes == ["ghostshell: the recording stopped: RuntimeError: sink gone"]
