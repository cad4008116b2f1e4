"""docs/wire-protocol.md "Refusals" and "Lockstep", checked on both boards (the Python board and the C
firmware, lockstep, over a pty): what is answered with a NACK (and which code), what is dropped silently
and counted in telemetry's ``link_errors``, and when an ADVANCE without frames trips the watchdog.

Every frame is built here byte by byte (protocol.framing.encode_raw_frame), as a third-party host would.
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from cobs import cobs

from protocol.codec import SCHEMA_HASH
from protocol.framing import crc16, encode_raw_frame
from protocol.messages import (
    PROTOCOL_VERSION, Ack, Advance, Config, ConfigKey, FaultFlags, Hello, MsgType, Nack, NackReason, ServoFrame,
    Telemetry,
)
from robots.registry import load_robot

from .wire import Wire

N = load_robot("coco").servo_count


@pytest.fixture(params=["python", "c"])
def board(request, tmp_path: Path):
    w = Wire(["--lockstep", "--firmware", request.param], tmp_path / "board.stderr")
    yield w
    assert w.close() == 130, (tmp_path / "board.stderr").read_text()[-2000:]


def _nack(w: Wire, seq: int) -> Nack:
    w.wait(lambda: any(n.ack_seq == seq for n in w.of(Nack)), what=f"NACK of seq {seq}")
    return next(n for n in w.of(Nack) if n.ack_seq == seq)


def _config(key: int, value: int) -> bytes:
    return struct.pack("<Bi", key, value)


def test_refusals_as_the_reference_says(board: Wire) -> None:
    board.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), seq=0)
    # well-formed but refused: a NACK whose ack_seq is the refused message's sequence number
    board.raw(encode_raw_frame(MsgType.CONFIG, 10, _config(9, 1)))  # unknown key (the codec cannot decode it)
    board.send(Config(ConfigKey.WATCHDOG_MS, 0), seq=11)  # value out of range
    board.send(ServoFrame(20_000, 1 << N, (0.0,)), seq=12)  # a mask bit beyond the robot's servos
    board.raw(encode_raw_frame(MsgType.ACK, 14, struct.pack("<HB", 0, MsgType.HELLO)))  # only the board sends ACK
    board.send(Hello(PROTOCOL_VERSION + 1, SCHEMA_HASH, 0), seq=15)  # HELLO payload version != 1
    board.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH ^ 1, 0), seq=16)  # another schema
    for seq, reason in ((10, NackReason.BAD_VALUE), (11, NackReason.BAD_VALUE), (12, NackReason.BAD_VALUE),
                        (14, NackReason.UNSUPPORTED), (15, NackReason.VERSION_MISMATCH),
                        (16, NackReason.SCHEMA_MISMATCH)):
        nack = _nack(board, seq)
        assert nack.reason == reason, (seq, nack)
    assert _nack(board, 10).msg_type == MsgType.CONFIG and _nack(board, 14).msg_type == MsgType.ACK
    # malformed: dropped without a reply, counted in telemetry link_errors
    good = encode_raw_frame(MsgType.HEARTBEAT, 20, struct.pack("<Q", 0))
    body = cobs.decode(good[:-1])
    bad_crc = cobs.encode(body[:-1] + bytes([body[-1] ^ 1])) + b"\x00"
    target_nan = struct.pack("<IHh", 40_000, 1, -32768)
    silent = [
        bad_crc,
        b"\x05\x01\x02\x03\x00",  # bad COBS (the first code byte points past the delimiter)
        encode_raw_frame(0x7F, 21, b""),  # unknown type
        encode_raw_frame(MsgType.HEARTBEAT, 22, struct.pack("<Q", 0), version=2),  # header version != 1
        encode_raw_frame(MsgType.HEARTBEAT, 23, struct.pack("<Q", 0) + b"\x00"),  # a byte after the payload
        encode_raw_frame(MsgType.HEARTBEAT, 24, struct.pack("<I", 0)),  # payload shorter than the layout
        encode_raw_frame(MsgType.SERVO_FRAME, 25, target_nan),  # target -32768
        encode_raw_frame(MsgType.CONFIG, 26, _config(9, 1) + b"\x00"),  # unknown key, wrong length
    ]
    hdr = struct.pack("<BBHB", PROTOCOL_VERSION, MsgType.HEARTBEAT, 27, 9) + struct.pack("<Q", 0)  # length 9, 8 sent
    silent.append(cobs.encode(hdr + struct.pack("<H", crc16(hdr))) + b"\x00")
    for raw in silent:
        board.raw(raw)
    board.send(Advance(40_000), seq=30)
    board.wait(lambda: len(board.of(Telemetry)) >= 2, what="two telemetry reports")
    first, second = board.of(Telemetry)[:2]
    assert first.link_errors == len(silent), first
    assert first.faults & FaultFlags.LINK_ERRORS and not second.faults & FaultFlags.LINK_ERRORS  # edge, counter stays
    assert second.link_errors == len(silent)
    assert first.last_applied_seq == 0 and first.buffer_fill == 0  # no frame applied yet
    answered = {n.ack_seq for n in board.of(Nack)} | {a.ack_seq for a in board.of(Ack)}
    assert not answered & set(range(20, 28)), answered


def test_advance_without_frames_holds_at_0_202_s(board: Wire) -> None:
    """The lockstep trap: an ADVANCE handled at board time 0 and nothing after it. The watchdog (200 ms)
    trips at the first tick more than 200 ms after the last valid message: the tick at 0.202 s."""
    board.send(Advance(400_000), seq=0)
    board.wait(lambda: any(t.board_time_us >= 400_000 for t in board.of(Telemetry)), what="telemetry to 0.4 s")
    held = {t.board_time_us: bool(t.faults & FaultFlags.WATCHDOG_HOLD) for t in board.of(Telemetry)}
    assert not held[200_000] and held[220_000], held  # the report after the tick at 0.200 s, then 0.220 s
    board.wait(lambda: "watchdog hold at board time 0.202000 s" in board.stderr.read_text(), what="hold line")
