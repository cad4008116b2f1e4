"""The serial transport's frame log is written from the loop after the send, and a log that fails is
one warning wherever its failure comes: in a slice, in the drain before ``close()``, or in the drain
before a schema switch (``set_servo_count``, run on every reconnect).

Over pyserial's ``loop://`` port (its own loopback: what is written is read back), so no board is
needed; the failing disk is a frame-log writer whose writes raise ENOSPC, as a full disk's do.
"""

from __future__ import annotations

import asyncio
import errno
from pathlib import Path
from typing import Any

import pytest

from host.link.transports.serial import SerialLinkTransport
from protocol.codec import schema_for
from protocol.framelog import iter_records
from protocol.logfile import JsonlFrameLog
from protocol.messages import Heartbeat


class _FullDisk(JsonlFrameLog):
    """A JSONL frame log on a disk that is full: every record's write fails."""

    closed_calls = 0

    def write_serial(self, *args: Any, **kwargs: Any) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    def close(self) -> None:
        type(self).closed_calls += 1
        super().close()


async def _transport(log: Path, full: bool = False) -> SerialLinkTransport:
    t = SerialLinkTransport("loop://", log_path=log)
    if full:
        t.framelog = _FullDisk(log, lazy=True)
    await t.connect(lambda items: None, lambda reason: None)
    return t


def _warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if "frame log" in r.getMessage()]


def test_records_are_written_after_the_send_in_order_with_the_send_time(tmp_path: Path) -> None:
    log = tmp_path / "host.jsonl"

    async def main() -> list[float]:
        t = await _transport(log)
        sent_at = []
        for seq in range(5):
            t.send(Heartbeat(seq), seq)
            sent_at.append(asyncio.get_running_loop().time())
        assert not log.exists() or not log.read_text()  # inside the sends: nothing written yet
        for _ in range(100):
            await asyncio.sleep(0)
        t.close()
        return sent_at

    sent_at = asyncio.run(main())
    with open(log, encoding="utf-8") as f:
        tx = [r for r in iter_records(f) if r["dir"] == "tx"]
    assert [r["seq"] for r in tx] == [0, 1, 2, 3, 4]
    assert [r["t"] for r in tx] == sorted(r["t"] for r in tx)
    assert tx[-1]["t"] <= sent_at[-1]  # stamped at the send (loop.time() is time.monotonic()), not at the write


def test_a_log_that_fails_in_the_drain_before_close_is_one_warning(tmp_path: Path,
                                                                   caplog: pytest.LogCaptureFixture) -> None:
    """The first failing write happens inside close(): no exception out of close (it used to raise
    AttributeError there, and a full disk at the end of a run crashed the session's exit)."""

    async def main() -> None:
        t = await _transport(tmp_path / "host.jsonl", full=True)
        t.send(Heartbeat(1), 1)
        t.send(Heartbeat(2), 2)
        t.close()  # before the loop came round: the close drains, the first write fails
        assert t.framelog is None

    _FullDisk.closed_calls = 0
    with caplog.at_level("WARNING", logger="host.link"):
        asyncio.run(main())
    assert len(_warnings(caplog)) == 1 and "No space left" in _warnings(caplog)[0]
    assert _FullDisk.closed_calls == 1  # the failing log was closed once


def test_a_log_that_fails_in_the_drain_before_a_schema_switch_is_one_warning(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """``set_servo_count`` (after CAPS, on every reconnect) drains first; a failure there stops the log
    and the switch still happens."""

    async def main() -> None:
        t = await _transport(tmp_path / "host.jsonl", full=True)
        t.send(Heartbeat(1), 1)
        t.set_servo_count(20)
        assert t.schema == schema_for(20) and t.framelog is None
        t.send(Heartbeat(2), 2)  # the link goes on without the log
        t.close()

    with caplog.at_level("WARNING", logger="host.link"):
        asyncio.run(main())
    assert len(_warnings(caplog)) == 1
