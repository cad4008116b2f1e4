"""``BoardClient.burst``: sends go on the wire together when the block ends, then are logged.

A start's FLUSH and first frame go out in one write (the board reads them in one read and handles
the frame right after the FLUSH); the frame log's records of them (JSON Lines: decode, render,
write) and the ``on_sent`` listeners (a run's recorder) follow, in send order, stamped with the
time of that write. A real board over a real pty receives both and answers the FLUSH.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import anyio
import pytest

from host.link import BoardClient
from protocol.framelog import iter_records
from protocol.messages import Flush, Message, ServoFrame

pytestmark = pytest.mark.timeout(60)


def _tx(log: Path) -> list[dict]:
    with open(log, encoding="utf-8") as f:
        return [r for r in iter_records(f) if r["dir"] == "tx"]


async def _logged(log: Path, *seqs: int) -> list[dict[str, Any]]:
    """The log's sent records of ``seqs``, in the log's order, once all are there (or after 100 passes of
    the loop): its lines are written from the loop after the send (``host.link.deferred.DeferredWork``),
    not inside it, and the link's own messages (TIME_SYNC, HEARTBEAT) may come between."""
    for _ in range(100):
        if set(seqs) <= {r["seq"] for r in _tx(log)}:
            break
        await anyio.sleep(0)
    return [r for r in _tx(log) if r["seq"] in seqs]


@pytest.mark.realtime  # tests/support/realtime_lock.py
def test_a_burst_is_one_write_logged_and_told_after_it(board_factory, tmp_path: Path) -> None:
    board = board_factory("--log", str(tmp_path / "board.jsonl"))
    log = tmp_path / "host.jsonl"
    told: list[tuple[int, str]] = []

    async def main() -> None:
        async with await BoardClient.connect(board.port, log_path=log) as c:
            c.on_sent.append(lambda seq, msg: told.append((seq, type(msg).__name__)))
            before = len(_tx(log))
            due = c.board_now_estimate() + 50_000
            with c.burst():
                flush_seq = c.send(Flush(due, 0b1))
                frame_seq = c.send_frame(ServoFrame(due, 0b1, (0.1,)))
                assert len(_tx(log)) == before and told == []  # not yet written, logged or told
                inside = time.monotonic()
            after = time.monotonic()
            sent = await _logged(log, flush_seq, frame_seq)
            assert [(r["seq"], r["type"]) for r in sent] == [(flush_seq, "FLUSH"), (frame_seq, "SERVO_FRAME")]
            assert inside <= sent[0]["t"] == sent[1]["t"] <= after  # the time of their one write
            assert told == [(flush_seq, "Flush"), (frame_seq, "ServoFrame")]
            # the board got both, and applied the frame (LinkTimeout otherwise)
            await c.wait_for(lambda t: t.last_applied_seq == frame_seq and t.board_time_us >= due, timeout=10)
            assert c.stats.frame_nacks == 0 and c.stats.decode_errors == 0
        with open(tmp_path / "board.jsonl", encoding="utf-8") as f:
            got = {r["seq"]: r["t"] for r in iter_records(f) if r["dir"] == "rx" and r["seq"] in (flush_seq, frame_seq)}
        assert got[flush_seq] == got[frame_seq]  # the board read them in one read

    anyio.run(main)


def test_a_burst_the_caller_leaves_with_an_error_still_writes_and_logs(board_factory, tmp_path: Path) -> None:
    board = board_factory("--lockstep")
    log = tmp_path / "host.jsonl"
    told: list[Message] = []

    async def main() -> None:
        async with await BoardClient.connect(board.port, log_path=log) as c:
            c.on_sent.append(lambda seq, msg: told.append(msg))
            seqs: list[int] = []
            with pytest.raises(RuntimeError), c.burst():
                seqs.append(c.send(Flush(c.board_now_estimate() + 20_000, 0b1)))
                raise RuntimeError("the caller failed half-way")
            assert [r["type"] for r in await _logged(log, *seqs)] == ["FLUSH"] and len(told) == 1
            with c.burst(), c.burst():  # nested: one block
                seqs.append(c.send(Flush(c.board_now_estimate() + 20_000, 0b1)))
            assert [r["seq"] for r in await _logged(log, *seqs)] == seqs and len(told) == 2
            # the port is not left corked: a FLUSH outside any block reaches the board, which ACKs it
            # (NackError / LinkTimeout otherwise)
            await c.flush(c.board_now_estimate() + 20_000, 0b1)

    anyio.run(main)


def test_an_await_inside_a_burst_is_refused_after_the_sends_are_told() -> None:
    from host.link.sent import AwaitInBurst, SentFanout

    fanout, told = SentFanout(), []
    fanout.listeners.append(lambda seq, msg: told.append(seq))

    async def awaits() -> None:
        with fanout.burst(None):
            fanout.sent(1, Flush(0, 1))
            await anyio.sleep(0)  # gives the loop a turn: another task could send in between
            fanout.sent(2, Flush(0, 1))

    with pytest.raises(AwaitInBurst, match="2 message"):
        anyio.run(awaits, backend="asyncio")
    assert told == [1, 2]  # nothing sent is lost


def test_a_burst_without_an_await_and_one_outside_a_loop_pass(monkeypatch: pytest.MonkeyPatch) -> None:
    import host.link.sent as sent

    markers: list = []
    make = sent._loop_marker
    monkeypatch.setattr(sent, "_loop_marker", lambda: markers.append(make()) or markers[-1])
    fanout, told = sent.SentFanout(), []
    fanout.listeners.append(lambda seq, msg: told.append(seq))

    async def plain() -> None:
        with fanout.burst(None):
            fanout.sent(1, Flush(0, 1))
            with fanout.burst(None):  # nested: one block, one marker
                fanout.sent(2, Flush(0, 1))
        await anyio.sleep(0)  # the loop runs: the marker was cancelled, so it does not fire now either

    anyio.run(plain, backend="asyncio")
    assert len(markers) == 1 and markers[0] is not None
    handle, ran = markers[0]
    assert handle.cancelled() and ran == []
    with fanout.burst(None):  # no running loop: nothing to check
        fanout.sent(3, Flush(0, 1))
    assert told == [1, 2, 3]


def test_a_frame_log_that_cannot_be_written_is_one_warning_and_the_link_goes_on(
        board_factory, caplog: pytest.LogCaptureFixture) -> None:
    """The host's frame log on a full disk (/dev/full: every line's write fails with ENOSPC). Its
    records are written from the loop after the send; the first that fails is one warning line, the
    log stops, and sending and receiving go on (the FLUSH below still gets its ACK)."""
    board = board_factory("--lockstep")

    async def main() -> None:
        async with await BoardClient.connect(board.port, log_path="/dev/full") as c:
            for _ in range(3):
                await c.flush(c.board_now_estimate() + 20_000, 0b1)  # NackError / LinkTimeout otherwise

    with caplog.at_level("WARNING", logger="host.link"):
        anyio.run(main)
    stopped = [r.getMessage() for r in caplog.records if "frame log" in r.getMessage()]
    assert len(stopped) == 1, stopped
    assert "/dev/full stopped" in stopped[0] and "No space left" in stopped[0]


def test_a_bursts_writer_hands_the_cpu_over_once_after_the_write(board_factory, tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """After a corked burst is written the writer blocks (``BURST_HANDOFF_S``), so the pty's hand-over
    to the board, queued on this CPU by the write, runs before the host's logging: once per burst,
    after the bytes went out, and never for a plain send."""
    import host.link.transports.serial as serial_module

    board = board_factory("--lockstep")
    waiting: list[int] = []  # bytes still waiting for the port at each hand-over

    async def main() -> None:
        async with await BoardClient.connect(board.port, log_path=tmp_path / "host.jsonl") as c:
            port = c.transport._port  # type: ignore[attr-defined]
            monkeypatch.setattr(serial_module, "_hand_over", lambda: waiting.append(len(port._tx)))
            c.send(Flush(0, 0b1))
            assert waiting == []  # a plain send does not hand over
            with c.burst():
                c.send(Flush(0, 0b1))
                c.send(Flush(0, 0b10))
                assert waiting == []
            assert waiting == [0]  # once, with the burst's bytes written

    anyio.run(main)
