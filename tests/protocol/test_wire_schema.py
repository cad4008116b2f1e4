"""Wire schemas: the u16-mask schema (1..16 servos, today's bytes and hash) and the u32-mask one (17..32)."""

from __future__ import annotations

import struct

import pytest
from cobs import cobs
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol import framelog
from protocol import messages as m
from protocol.codec import (
    MAX_PAYLOAD,
    SCHEMA_HASH,
    WIRE_SCHEMA_16,
    WIRE_SCHEMA_32,
    PayloadError,
    WireBoundError,
    decode_payload,
    encode_payload,
    schema_by_hash,
    schema_for,
)
from protocol.framing import DecodeError, DecodeErrorKind, Frame, FrameDecoder, encode_frame
from protocol.messages import MAX_WIRE_SERVOS, MsgType
from protocol.testing.samples import servo_frame_n, telemetry_n

#: (servos, SERVO_FRAME payload, TELEMETRY payload, SERVO_FRAME wire bytes, TELEMETRY wire bytes): the
#: table in protocol.codec's docstring
SIZES = [(1, 8, 41, 17, 50), (12, 30, 107, 39, 116), (16, 38, 131, 47, 140), (17, 42, 137, 51, 146),
         (32, 72, 227, 81, 236)]


def test_the_16_schema_is_the_protocol_as_it_was() -> None:
    assert WIRE_SCHEMA_16.hash == SCHEMA_HASH == 0x1D7AD3A3  # tests/protocol/test_codec.py pins it too (SERVO_FAULT added)
    assert WIRE_SCHEMA_32.hash != SCHEMA_HASH
    assert schema_by_hash(SCHEMA_HASH) is WIRE_SCHEMA_16 and schema_by_hash(WIRE_SCHEMA_32.hash) is WIRE_SCHEMA_32
    assert schema_by_hash(SCHEMA_HASH ^ 1) is None
    assert "mask32[max=32]" in WIRE_SCHEMA_32.text and "mask16[max=16]" in WIRE_SCHEMA_16.text


@pytest.mark.parametrize("n", range(1, MAX_WIRE_SERVOS + 1))
def test_schema_for_every_servo_count(n: int) -> None:
    assert schema_for(n) is (WIRE_SCHEMA_16 if n <= 16 else WIRE_SCHEMA_32)


@pytest.mark.parametrize("n", [0, -1, 33, 64])
def test_a_servo_count_the_wire_cannot_carry_is_refused(n: int) -> None:
    with pytest.raises(WireBoundError, match="the wire carries 1 to 32"):
        schema_for(n)


@pytest.mark.parametrize(("n", "sf_payload", "tel_payload", "sf_wire", "tel_wire"), SIZES)
def test_sizes_per_servo_count(n: int, sf_payload: int, tel_payload: int, sf_wire: int, tel_wire: int) -> None:
    s = schema_for(n)
    assert len(s.encode_payload(servo_frame_n(n))) == sf_payload
    assert len(s.encode_payload(telemetry_n(n))) == tel_payload <= MAX_PAYLOAD
    assert len(encode_frame(servo_frame_n(n), 1, s)) == sf_wire
    assert len(encode_frame(telemetry_n(n), 1, s)) == tel_wire


def test_the_mask_is_a_u32_above_16_servos() -> None:
    frame = servo_frame_n(32)
    payload = WIRE_SCHEMA_32.encode_payload(frame)
    assert struct.unpack_from("<II", payload) == (frame.apply_at_us, 0xFFFF_FFFF)
    body = cobs.decode(encode_frame(frame, 9, WIRE_SCHEMA_32)[:-1])
    assert body[1] == MsgType.SERVO_FRAME and struct.unpack_from("<I", body, 5 + 4)[0] == 0xFFFF_FFFF
    # the 16 schema refuses what it cannot carry, both ways
    with pytest.raises(PayloadError, match="outside the 16 servos"):
        encode_payload(frame)
    with pytest.raises(PayloadError):
        decode_payload(MsgType.SERVO_FRAME, payload)
    with pytest.raises(PayloadError, match="at most 16"):
        encode_payload(telemetry_n(17))
    with pytest.raises(PayloadError, match="outside the 32 servos"):
        WIRE_SCHEMA_32.encode_payload(m.ServoFrame(0, 1 << 32, (0.0,)))


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 32), st.data())
def test_round_trip_and_no_frame_decodes_under_the_other_schema(n: int, data: st.DataObject) -> None:
    """What one schema encodes, the other never decodes differently: a SERVO_FRAME or FLUSH fails its
    length check, a TELEMETRY decodes the same (why a log before its HELLO decodes unambiguously)."""
    s = schema_for(n)
    other = WIRE_SCHEMA_32 if s is WIRE_SCHEMA_16 else WIRE_SCHEMA_16
    mask = data.draw(st.integers(1, (1 << n) - 1))
    targets = tuple(data.draw(st.floats(-3.0, 3.0)) for _ in range(mask.bit_count()))
    for msg in (m.ServoFrame(data.draw(st.integers(0, 2**32 - 1)), mask, targets), m.Flush(123, mask), telemetry_n(n)):
        t = m.MsgType.SERVO_FRAME if isinstance(msg, m.ServoFrame) else (
            m.MsgType.FLUSH if isinstance(msg, m.Flush) else m.MsgType.TELEMETRY)
        payload = s.encode_payload(msg)
        assert s.decode_payload(t, payload) == s.quantize_message(msg)
        try:
            again = other.decode_payload(t, payload)
        except PayloadError:
            continue
        assert t is m.MsgType.TELEMETRY and again == s.decode_payload(t, payload)


def test_frame_decoder_takes_the_sessions_schema() -> None:
    wire = encode_frame(servo_frame_n(20), 5, WIRE_SCHEMA_32)
    (item,) = FrameDecoder(schema=WIRE_SCHEMA_32).feed(wire)
    assert isinstance(item, Frame) and item.msg.mask == (1 << 20) - 1  # type: ignore[union-attr]
    (bad,) = FrameDecoder().feed(wire)
    assert isinstance(bad, DecodeError) and bad.kind is DecodeErrorKind.PAYLOAD


def test_log_decoder_follows_hello_and_caps() -> None:
    """A log names its schema in HELLO/CAPS; before them the first schema that decodes wins."""
    s = WIRE_SCHEMA_32
    raws = [
        encode_frame(telemetry_n(20), 1, s),  # a realtime board's report before any host
        encode_frame(m.Hello(1, s.hash, 0), 0, s),
        encode_frame(servo_frame_n(20), 1, s),
        encode_frame(m.Flush(0, 1 << 19), 2, s),
    ]
    dec = framelog.LogDecoder()
    items = [dec.decode(r.hex()) for r in raws]
    assert all(isinstance(i, Frame) for i in items), items
    assert dec.schema is s
    assert items[3].msg == m.Flush(0, 1 << 19)  # type: ignore[union-attr]
    # pinned: exactly that schema, no guessing
    pinned = framelog.LogDecoder(WIRE_SCHEMA_16)
    assert isinstance(pinned.decode(raws[2]), DecodeError) and pinned.schema is WIRE_SCHEMA_16
    # a log of a robot of up to 16 servos decodes as it always did
    old = framelog.LogDecoder()
    assert isinstance(old.decode(encode_frame(servo_frame_n(12), 3)), Frame) and old.schema is None
