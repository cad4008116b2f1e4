"""The board's serial transport on a real pty: frames in, frames out, wire-time model, frame log."""

from __future__ import annotations

import json
import os
import select
from pathlib import Path

import pytest

from firmware_sim.transports import open_board_transport
from firmware_sim.transports.serial import SerialBoardTransport
from protocol.framing import DecodeError, Frame, FrameDecoder, encode_frame
from protocol.messages import Ack, Heartbeat, MsgType


def _open_slave(t: SerialBoardTransport) -> int:
    fd = os.open(t.name, os.O_RDWR | os.O_NOCTTY)
    os.set_blocking(fd, False)
    return fd


def _read_all(fd: int) -> bytes:
    out = b""
    while select.select([fd], [], [], 0.5)[0]:
        try:
            chunk = os.read(fd, 65536)
        except BlockingIOError:
            break
        out += chunk
        if out.endswith(b"\x00"):
            break
    return out


def test_messages_both_ways_with_log(tmp_path: Path) -> None:
    log = tmp_path / "board.jsonl"
    t = open_board_transport("pty", log_path=str(log))
    assert isinstance(t, SerialBoardTransport) and t.name.startswith("/dev/") and t.fileno() is not None
    t.log_time = lambda: 1.25
    host = _open_slave(t)
    try:
        os.write(host, encode_frame(Heartbeat(7), 65535) + b"\x05junk\x00")
        select.select([t.fileno()], [], [], 2)
        items = t.receive(0.0)
        assert isinstance(items[0], Frame) and items[0].seq == 65535 and items[0].msg == Heartbeat(7)
        assert isinstance(items[1], DecodeError)
        t.queue(Ack(65535, MsgType.HEARTBEAT), 3, 0.0)
        assert t.backlog > 0
        t.flush(0.0)
        got = FrameDecoder().feed(_read_all(host))
        assert isinstance(got[0], Frame) and got[0].seq == 3 and got[0].msg == Ack(65535, MsgType.HEARTBEAT)
        assert t.backlog == 0
    finally:
        os.close(host)
        t.close()
    recs = [json.loads(line) for line in log.read_text().splitlines()]
    assert [r["dir"] for r in recs] == ["rx", "rx", "tx"] and all(r["t"] == 1.25 for r in recs)
    assert recs[0]["seq"] == 65535 and "error" in recs[1]


def test_wire_model_holds_bytes_for_their_wire_time() -> None:
    t = SerialBoardTransport("pty", baud=10_000)  # 1 ms per byte
    host = _open_slave(t)
    try:
        raw = encode_frame(Heartbeat(1), 0)
        t.queue(Heartbeat(1), 0, 100.0)
        assert t.next_io_time() == pytest.approx(100.0 + len(raw) * 1e-3)
        assert t.tx_busy_s(100.0) == pytest.approx(len(raw) * 1e-3)
        t.flush(100.0)  # not on the wire yet
        assert t.backlog == len(raw) and not t.wants_write
        t.flush(100.0 + len(raw) * 1e-3)
        assert t.backlog == 0 and _read_all(host) == raw
        os.write(host, raw)
        select.select([t.fileno()], [], [], 2)
        assert t.receive(200.0) == []  # read, held back by the model
        assert t.next_io_time() == pytest.approx(200.0 + len(raw) * 1e-3)
        items = t.receive(200.0 + len(raw) * 1e-3, read=False)
        assert len(items) == 1 and isinstance(items[0], Frame)
    finally:
        os.close(host)
        t.close()


def test_a_fault_wrapped_line_reports_the_same_wire_time() -> None:
    """``--faults`` wraps both wire models; the transmit backlog the board stamps TIME_SYNC replies
    and drops periodic telemetry by must still be the line's, not 0."""
    from firmware_sim.transports.faulty import install_faults
    from protocol.faults import FaultSpec

    t = SerialBoardTransport("pty", baud=10_000)  # 1 ms per byte
    try:
        install_faults(t, FaultSpec.parse("drop=0.5"), seed=3)
        raw = encode_frame(Heartbeat(1), 0)
        t.queue(Heartbeat(1), 0, 100.0)
        assert t.tx_busy_s(100.0) == pytest.approx(len(raw) * 1e-3)
        assert t.tx_busy_s(100.0 + len(raw) * 1e-3 + 1.0) == 0.0
    finally:
        t.close()


def test_a_time_sync_reply_is_stamped_for_when_it_goes_on_the_wire() -> None:
    """Over a modelled line a TIME_SYNC_REPLY queues behind what is already on the wire; its t3 is
    the board time its first byte goes out (transmit timestamping), so the host's NTP offset does
    not take the queue for path asymmetry. A realtime board over a real pty at 9 600 baud."""
    import time

    from firmware_sim.board import Board
    from firmware_sim.config import BoardConfig
    from firmware_sim.server import BoardServer
    from protocol.messages import TimeSyncReply

    t = SerialBoardTransport("pty", baud=9_600)
    host = _open_slave(t)
    try:
        server = BoardServer(Board(BoardConfig(lockstep=False)), t)
        server.send([Heartbeat(i) for i in range(10)])  # ~120 B: ~125 ms of wire
        busy = t.tx_busy_s(time.monotonic())
        assert busy > 0.1
        server.send([TimeSyncReply(1, 1_000, 2_000)])
        t.flush(time.monotonic() + 10.0)  # release everything the model holds, as if 10 s had passed
        frames = [i for i in FrameDecoder().feed(_read_all(host)) if isinstance(i, Frame)]
        (reply,) = [f.msg for f in frames if isinstance(f.msg, TimeSyncReply)]
        shift = reply.t3_board_us - 2_000
        assert 0.5 * busy * 1e6 < shift <= busy * 1e6 + 1_000  # the queue it waited behind, not 0
        assert reply.t2_board_us == 1_000  # the receive stamp is left alone
        assert t.tx_busy_s(time.monotonic() + 100.0) == 0.0  # an idle line is never "negatively" busy
    finally:
        os.close(host)
        t.close()
