"""``BoardClient.burst``: sends go on the wire at once, their logging follows the block.

A start's FLUSH and first frame are written back to back; the frame log's records of them (JSON
Lines: decode, render, write) and the ``on_sent`` listeners (a run's recorder) wait for the end of
the block, in send order, with the times the frames were written. A real board over a real pty
receives both and answers the FLUSH.
"""

from __future__ import annotations

import time
from pathlib import Path

import anyio
import pytest

from host.link import BoardClient
from protocol.framelog import iter_records
from protocol.messages import Flush, Message, ServoFrame

pytestmark = pytest.mark.timeout(60)


def _tx(log: Path) -> list[dict]:
    with open(log, encoding="utf-8") as f:
        return [r for r in iter_records(f) if r["dir"] == "tx"]


def test_a_burst_logs_and_tells_listeners_after_its_writes(board_factory, tmp_path: Path) -> None:
    board = board_factory("--lockstep")
    log = tmp_path / "host.jsonl"
    told: list[tuple[int, str]] = []

    async def main() -> None:
        async with await BoardClient.connect(board.port, log_path=log) as c:
            c.on_sent.append(lambda seq, msg: told.append((seq, type(msg).__name__)))
            before = len(_tx(log))
            due = c.board_now_estimate() + 20_000
            with c.burst():
                flush_seq = c.send(Flush(due, 0b1))
                frame_seq = c.send_frame(ServoFrame(due, 0b1, (0.1,)))
                assert len(_tx(log)) == before and told == []  # written, not yet logged or told
                written = time.monotonic()
            sent = _tx(log)[before:]
            assert [(r["seq"], r["type"]) for r in sent] == [(flush_seq, "FLUSH"), (frame_seq, "SERVO_FRAME")]
            assert sent[0]["t"] <= sent[1]["t"] <= written  # the times they were written, not logged
            assert told == [(flush_seq, "Flush"), (frame_seq, "ServoFrame")]
            with anyio.fail_after(10):  # the board got both: it answers the FLUSH
                await c.advance(due + 20_000)
            assert c.stats.frame_nacks == 0 and c.stats.decode_errors == 0

    anyio.run(main)


def test_a_send_that_fails_inside_a_burst_still_logs_what_went_out(board_factory, tmp_path: Path) -> None:
    board = board_factory("--lockstep")
    log = tmp_path / "host.jsonl"
    told: list[Message] = []

    async def main() -> None:
        async with await BoardClient.connect(board.port, log_path=log) as c:
            c.on_sent.append(lambda seq, msg: told.append(msg))
            before = len(_tx(log))
            with pytest.raises(RuntimeError), c.burst():
                c.send(Flush(c.board_now_estimate() + 20_000, 0b1))
                raise RuntimeError("the caller failed half-way")
            assert [r["type"] for r in _tx(log)[before:]] == ["FLUSH"] and len(told) == 1
            with c.burst(), c.burst():  # nested: one block
                c.send(Flush(c.board_now_estimate() + 20_000, 0b1))
            assert len(_tx(log)) == before + 2 and len(told) == 2

    anyio.run(main)
