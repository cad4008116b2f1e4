"""Serial framing: CRC, size budget, chunking, garbage, truncation, corruption, bounded buffer."""

from __future__ import annotations

import crcmod.predefined
import pytest
from cobs import cobs
from hypothesis import given
from hypothesis import strategies as st

from protocol import messages as m
from protocol.codec import MAX_CHUNK_DATA, encode_payload, quantize_message
from protocol.framing import (
    CRC_CHECK,
    CRC_NAME,
    CRC_SIZE,
    HEADER_SIZE,
    MAX_WIRE_FRAME,
    WIRE_OVERHEAD,
    DecodeError,
    DecodeErrorKind,
    Frame,
    FrameDecoder,
    crc16,
    encode_frame,
    encode_raw_frame,
    frame_size,
)
from protocol.messages import MsgType
from protocol.testing.samples import SAMPLES, servo_frame_12, telemetry_12

SAMPLE_LIST = list(SAMPLES.values())

#: A stream of sample messages with their sequence numbers.
streams = st.lists(st.sampled_from(SAMPLE_LIST), min_size=1, max_size=12).map(
    lambda msgs: [(msg, 1000 + i) for i, msg in enumerate(msgs)]
)


def wire_of(stream) -> list[bytes]:
    return [encode_frame(msg, seq) for msg, seq in stream]


def frames(items) -> list[tuple[int, m.Message]]:
    return [(i.seq, i.msg) for i in items if isinstance(i, Frame)]


def expected(stream, indices=None) -> list[tuple[int, m.Message]]:
    return [(seq, quantize_message(msg)) for k, (msg, seq) in enumerate(stream) if indices is None or k in indices]


def feed_all(dec: FrameDecoder, chunks) -> list:
    out = []
    for c in chunks:
        out += dec.feed(c)
    return out


# --- CRC and sizes -------------------------------------------------------------------------


def test_crc_is_the_catalogued_x25_with_its_check_value() -> None:
    assert CRC_NAME == "x-25"
    assert crc16(b"123456789") == CRC_CHECK == 0x906E
    assert crcmod.predefined.mkPredefinedCrcFun(CRC_NAME)(b"123456789") == 0x906E


def test_frame_layout_is_as_documented() -> None:
    msg = m.Flush(from_us=0x0102030405060708, mask=0x0A0B)
    wire = encode_frame(msg, 0x1234)
    body = cobs.decode(wire[:-1])
    payload = encode_payload(msg)
    assert body[:HEADER_SIZE] == bytes([1, MsgType.FLUSH, 0x34, 0x12, len(payload)])
    assert body[HEADER_SIZE:-CRC_SIZE] == payload == bytes.fromhex("0807060504030201") + b"\x0b\x0a"
    assert int.from_bytes(body[-CRC_SIZE:], "little") == crc16(body[:-CRC_SIZE])
    assert len(wire) == len(payload) + WIRE_OVERHEAD


@given(
    st.integers(0, 2**64),
    st.lists(st.floats(allow_nan=False), min_size=12, max_size=12),
    st.integers(0, 2**16 - 1),
)
def test_twelve_servo_frame_fits_40_bytes(t: int, targets: list[float], seq: int) -> None:
    wire = encode_frame(m.ServoFrame(apply_at_us=t, mask=0x0FFF, targets=tuple(targets)), seq)
    assert len(wire) <= 40
    assert len(wire) == 39


def test_frame_size_and_largest_frames() -> None:
    assert frame_size(servo_frame_12()) == 39
    assert frame_size(telemetry_12()) == 5 + 8 + 3 * (1 + 24) + 6 + 2 + 2 + 2 + 12 + 2 + 2
    big = m.CameraChunk(request_id=1, index=0, total=1, data=bytes(range(1, 256))[:MAX_CHUNK_DATA])
    wire = encode_frame(big, 1)
    assert len(wire) <= MAX_WIRE_FRAME
    assert frames(FrameDecoder().feed(wire)) == [(1, big)]


# --- chunking, garbage, truncation -----------------------------------------------------------


@given(streams, st.data())
def test_arbitrary_chunking_gives_the_same_messages(stream, data) -> None:
    wire = b"".join(wire_of(stream))
    cuts = sorted(data.draw(st.lists(st.integers(0, len(wire)), max_size=20)))
    chunks = [wire[a:b] for a, b in zip([0, *cuts], [*cuts, len(wire)])]
    dec = FrameDecoder()
    items = feed_all(dec, chunks)
    assert all(isinstance(i, Frame) for i in items)
    assert frames(items) == expected(stream)
    assert dec.frames_ok == len(stream) and dec.bytes_discarded == 0 and dec.pending == 0


def test_byte_by_byte_feeding() -> None:
    stream = [(msg, i) for i, msg in enumerate(SAMPLE_LIST)]
    wire = b"".join(wire_of(stream))
    dec = FrameDecoder()
    items = feed_all(dec, [wire[i : i + 1] for i in range(len(wire))])
    assert frames(items) == expected(stream)


@given(streams, st.data())
def test_garbage_between_frames_loses_only_the_frame_it_touches(stream, data) -> None:
    """Garbage merges with the following frame unless it ends in 0x00; nothing else is lost."""
    wires = wire_of(stream)
    garbage = [data.draw(st.binary(max_size=80), label=f"garbage before {k}") for k in range(len(wires) + 1)]
    line = b"".join(g + w for g, w in zip(garbage, wires)) + garbage[-1]
    touched = {k for k, g in enumerate(garbage[:-1]) if g and not g.endswith(b"\x00")}
    dec = FrameDecoder()
    items = feed_all(dec, [line[i : i + 7] for i in range(0, len(line), 7)])
    got = frames(items)
    must = expected(stream, set(range(len(stream))) - touched)
    assert [x for x in got if x in must] == must  # every untouched frame, in order
    assert all(x in expected(stream) for x in got)  # nothing invented
    assert dec.pending <= len(garbage[-1])
    for item in items:
        assert isinstance(item, (Frame, DecodeError))


@given(st.sampled_from(SAMPLE_LIST), st.data())
def test_truncated_frame_then_a_good_one(msg, data) -> None:
    wire = encode_frame(msg, 5)
    cut = data.draw(st.integers(1, len(wire) - 2))
    good = encode_frame(SAMPLES[MsgType.HEARTBEAT], 6)
    # (a) the sender stopped mid-frame and the line saw a delimiter (e.g. a reconnect flush)
    dec = FrameDecoder()
    items = dec.feed(wire[:cut] + b"\x00" + good)
    assert [type(i) for i in items] == [DecodeError, Frame]
    assert items[0].kind in {DecodeErrorKind.COBS, DecodeErrorKind.CRC, DecodeErrorKind.LENGTH}
    assert frames(items) == [(6, SAMPLES[MsgType.HEARTBEAT])]
    # (b) no delimiter: the stub merges with the next frame, which is lost; the one after survives
    dec = FrameDecoder()
    items = dec.feed(wire[:cut] + good + good)
    assert [type(i) for i in items] == [DecodeError, Frame]
    assert dec.bytes_discarded == cut + len(good)


def test_corrupted_length_field() -> None:
    msg = SAMPLES[MsgType.TELEMETRY]
    payload = encode_payload(msg)
    next_good = encode_frame(SAMPLES[MsgType.ACK], 2)
    # on the wire: the CRC catches it
    body = bytearray(cobs.decode(encode_frame(msg, 1)[:-1]))
    body[4] ^= 0x04
    items = FrameDecoder().feed(cobs.encode(bytes(body)) + b"\x00" + next_good)
    assert [getattr(i, "kind", None) for i in items] == [DecodeErrorKind.CRC, None]
    # a sender bug (wrong length, CRC computed over it): reported as LENGTH
    for wrong in (0, len(payload) - 1, len(payload) + 1, 255):
        body = bytearray(cobs.decode(encode_raw_frame(MsgType.TELEMETRY, 1, payload)[:-1]))
        body[4] = wrong
        body[-2:] = crc16(bytes(body[:-2])).to_bytes(2, "little")
        dec = FrameDecoder()
        items = dec.feed(cobs.encode(bytes(body)) + b"\x00" + next_good)
        assert items[0].kind is DecodeErrorKind.LENGTH and str(len(payload)) in items[0].detail
        assert frames(items) == [(2, SAMPLES[MsgType.ACK])]
        assert dec.errors[DecodeErrorKind.LENGTH] == 1


@given(st.sampled_from(SAMPLE_LIST), st.data())
def test_any_single_bit_flip_is_caught_by_the_crc(msg, data) -> None:
    body = bytearray(cobs.decode(encode_frame(msg, 9)[:-1]))
    bit = data.draw(st.integers(0, 8 * len(body) - 1))
    body[bit // 8] ^= 1 << (bit % 8)
    items = FrameDecoder().feed(cobs.encode(bytes(body)) + b"\x00")
    assert len(items) == 1 and items[0].kind is DecodeErrorKind.CRC


@given(st.sampled_from(SAMPLE_LIST), st.data())
def test_bit_flips_on_the_wire_lose_only_that_frame(msg, data) -> None:
    before, after = SAMPLES[MsgType.HEARTBEAT], SAMPLES[MsgType.FLUSH]
    wire = bytearray(encode_frame(msg, 9))
    flips = data.draw(st.lists(st.integers(0, 8 * (len(wire) - 1) - 1), min_size=1, max_size=3, unique=True))
    for bit in flips:  # any bits except the delimiter's
        wire[bit // 8] ^= 1 << (bit % 8)
    line = encode_frame(before, 8) + bytes(wire) + encode_frame(after, 10)
    items = FrameDecoder().feed(line)
    got = frames(items)
    assert got[0] == (8, before) and got[-1] == (10, quantize_message(after))
    if len(got) == 3:  # a flip that leaves the decoded message unchanged would be a CRC collision
        assert got[1] == (9, quantize_message(msg)) and bytes(wire) == encode_frame(msg, 9)
    assert all(isinstance(i, DecodeError) for i in items if not isinstance(i, Frame))


def test_version_unknown_type_and_payload_errors() -> None:
    payload = encode_payload(SAMPLES[MsgType.HEARTBEAT])
    dec = FrameDecoder()
    items = dec.feed(
        encode_raw_frame(MsgType.HEARTBEAT, 1, payload, version=2)
        + encode_raw_frame(0x7E, 2, b"")
        + encode_raw_frame(MsgType.HEARTBEAT, 3, payload[:-1])
        + encode_raw_frame(MsgType.HEARTBEAT, 4, payload)
        + b"\x00\x00\x00"  # idle delimiters are ignored
        + b"\x01\x01\x00"  # too short for a header
    )
    kinds = [getattr(i, "kind", None) for i in items]
    assert kinds == [
        DecodeErrorKind.VERSION,
        DecodeErrorKind.UNKNOWN_TYPE,
        DecodeErrorKind.PAYLOAD,
        None,
        DecodeErrorKind.LENGTH,
    ]
    assert "version 2" in items[0].detail and "0x7e" in items[1].detail and "truncated" in items[2].detail
    assert items[3].seq == 4
    assert dec.frames_ok == 1 and dec.error_count == 4


def test_invalid_cobs() -> None:
    items = FrameDecoder().feed(b"\x05\x01\x00")  # code byte says 4 more bytes follow
    assert len(items) == 1 and items[0].kind is DecodeErrorKind.COBS
    assert items[0].raw == b"\x05\x01\x00"


# --- bounded buffer --------------------------------------------------------------------------


def test_endless_stream_without_delimiter_stays_bounded() -> None:
    dec = FrameDecoder(max_frame_bytes=300)
    fed = 0
    for i in range(2000):
        chunk = bytes([(i % 255) + 1]) * 517
        items = dec.feed(chunk)
        fed += len(chunk)
        assert dec.pending <= 300
        if i == 0:
            assert [x.kind for x in items] == [DecodeErrorKind.OVERSIZE]
            assert len(items[0].raw) == 300
        else:
            assert items == []
    assert dec.errors[DecodeErrorKind.OVERSIZE] == 1 and dec.error_count == 1
    assert dec.bytes_discarded + dec.pending == fed == dec.bytes_received
    # resync: the frame whose delimiter ends the run is lost, the next one decodes
    a, b = encode_frame(SAMPLES[MsgType.ACK], 1), encode_frame(SAMPLES[MsgType.ACK], 2)
    assert frames(dec.feed(a + b)) == [(2, SAMPLES[MsgType.ACK])]
    assert dec.bytes_discarded == fed + len(a)


def test_oversize_run_delivered_in_one_chunk_with_its_delimiter() -> None:
    dec = FrameDecoder(max_frame_bytes=300)
    good = encode_frame(SAMPLES[MsgType.ACK], 3)
    items = dec.feed(b"\x07" * 1000 + b"\x00" + good)
    assert [getattr(i, "kind", None) for i in items] == [DecodeErrorKind.OVERSIZE, None]
    assert dec.bytes_discarded == 1001 and dec.pending == 0


def test_max_frame_bytes_must_fit_the_longest_frame() -> None:
    with pytest.raises(ValueError, match="at least"):
        FrameDecoder(max_frame_bytes=MAX_WIRE_FRAME - 1)


@given(st.lists(st.binary(max_size=600), max_size=30))
def test_decoder_never_raises_and_stays_bounded(chunks: list[bytes]) -> None:
    dec = FrameDecoder(max_frame_bytes=MAX_WIRE_FRAME)
    for c in chunks:
        for item in dec.feed(c):
            assert isinstance(item, (Frame, DecodeError))
        assert dec.pending <= MAX_WIRE_FRAME
    assert dec.bytes_received == sum(map(len, chunks))


def test_reset_drops_partial_bytes() -> None:
    dec = FrameDecoder()
    wire = encode_frame(SAMPLES[MsgType.ACK], 1)
    dec.feed(b"junk")
    dec.reset()
    assert dec.pending == 0 and dec.bytes_discarded == 4
    assert frames(dec.feed(wire)) == [(1, SAMPLES[MsgType.ACK])]
