"""Frame-log records: build, serialise, parse, re-decode from raw bytes, format."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest

from protocol import messages as m
from protocol.codec import quantize_message
from protocol.framelog import (
    FrameLogError,
    decode_raw,
    format_record,
    from_line,
    iter_records,
    record,
    to_line,
)
from protocol.framing import DecodeError, DecodeErrorKind, Frame, FrameDecoder, encode_frame
from protocol.messages import MsgType
from protocol.testing.samples import SAMPLES


@pytest.mark.parametrize("t", list(MsgType), ids=lambda t: t.name)
def test_every_type_logs_round_trips_and_re_decodes(t: MsgType) -> None:
    msg = SAMPLES[t]
    wire = encode_frame(msg, 77)
    (frame,) = FrameDecoder().feed(wire)
    rec = record("rx", 12.5, wire, frame)
    line = to_line(rec)
    assert "\n" not in line
    back = from_line(line)
    assert back == json.loads(json.dumps(rec)) == rec
    assert back["type"] == t.name and back["seq"] == 77 and back["raw"] == wire.hex()
    again = decode_raw(back["raw"])
    assert isinstance(again, Frame) and again.msg == quantize_message(msg) and again.raw == wire
    assert record("rx", 12.5, wire) == rec  # item=None decodes the raw bytes itself
    text = format_record(back)
    assert t.name in text and "rx" in text and "#   77" in text and f"{len(wire)} B" in text


def test_fields_render_enums_flags_bytes_and_nan() -> None:
    tel = m.Telemetry(
        board_time_us=1,
        positions=(math.nan, 0.5),
        velocities=(),
        efforts=(),
        imu_rpy=(0.0, 0.0, 0.0),
        faults=m.FaultFlags.ESTOP | m.FaultFlags.LINK_ERRORS,
        buffer_fill=0,
        last_applied_seq=0,
        late_count=0,
        dropped_count=0,
        link_errors=0,
    )
    fields = record("rx", 0.0, encode_frame(tel, 1))["fields"]
    assert fields["positions"] == [None, 0.5]
    assert fields["faults"] == "ESTOP|LINK_ERRORS"
    nack = record("rx", 0.0, encode_frame(SAMPLES[MsgType.NACK], 1))["fields"]
    assert nack["msg_type"] == "SERVO_FRAME" and nack["reason"] == "LATE"
    chunk = record("rx", 0.0, encode_frame(SAMPLES[MsgType.CAMERA_CHUNK], 1))
    assert chunk["fields"]["data"] == SAMPLES[MsgType.CAMERA_CHUNK].data.hex()
    assert "data=<28 B>" in format_record(chunk)
    none = record("tx", 0.0, encode_frame(m.Telemetry(0, (), (), (), (0, 0, 0), m.FaultFlags.NONE, 0, 0, 0, 0, 0), 1))
    assert none["fields"]["faults"] == "NONE"


def test_error_records() -> None:
    wire = bytearray(encode_frame(SAMPLES[MsgType.SERVO_FRAME], 3))
    wire[10] ^= 0x40
    (err,) = FrameDecoder().feed(bytes(wire))
    assert isinstance(err, DecodeError)
    rec = record("rx", 1.0, err.raw, err)
    assert rec["error"] == err.kind.value and rec["detail"] == err.detail and "fields" not in rec
    back = from_line(to_line(rec))
    redecoded = decode_raw(back["raw"])
    assert isinstance(redecoded, DecodeError) and redecoded.kind is err.kind
    assert f"ERROR {err.kind.value}" in format_record(back)


def test_decode_raw_edge_cases() -> None:
    wire = encode_frame(SAMPLES[MsgType.ACK], 1)
    assert isinstance(decode_raw(wire[:-1]), Frame)  # delimiter optional
    assert isinstance(decode_raw(wire.hex().upper()), Frame)
    empty = decode_raw("")
    assert isinstance(empty, DecodeError) and "empty" in empty.detail
    two = decode_raw(wire + wire)
    assert isinstance(two, DecodeError) and "expected one" in two.detail
    with pytest.raises(FrameLogError, match="hex"):
        decode_raw("zz")


@pytest.mark.parametrize(
    ("line", "needle"),
    [
        ("", "empty"),
        ("not json", "not JSON"),
        ("[1, 2]", "JSON object"),
        ('{"dir": "up", "t": 1, "raw": ""}', "'dir'"),
        ('{"dir": "tx", "t": "soon", "raw": ""}', "'t'"),
        ('{"dir": "tx", "t": true, "raw": ""}', "'t'"),
        ('{"dir": "tx", "t": 1, "raw": 5}', "'raw'"),
        ('{"dir": "tx", "t": 1, "raw": "abc"}', "not valid hex"),
        ('{"dir": "tx", "t": 1, "raw": "00"}', "'type' and 'fields'"),
        ('{"dir": "tx", "t": 1, "raw": "00", "error": 3}', "'error'"),
    ],
)
def test_bad_lines_raise_clear_errors(line: str, needle: str) -> None:
    with pytest.raises(FrameLogError, match=needle):
        from_line(line)


def test_iter_records_names_the_line() -> None:
    good = to_line(record("tx", 0.5, encode_frame(SAMPLES[MsgType.HEARTBEAT], 1)))
    assert len(list(iter_records([good, "", good + "\n"]))) == 2
    with pytest.raises(FrameLogError, match="line 3: not JSON"):
        list(iter_records([good, good, "{oops"]))


def test_record_rejects_bad_direction_and_nan_never_reaches_json() -> None:
    with pytest.raises(ValueError, match="direction"):
        record("sideways", 0.0, b"\x00")
    rec = record("tx", 0.0, b"\x00")
    assert rec["error"] == DecodeErrorKind.LENGTH.value
    to_line(rec)  # serialisable with allow_nan=False


def _fields_as_first_written(msg: object) -> dict[str, object]:
    """``message_fields`` as it was before its fast paths (the reference it must still equal)."""
    import dataclasses
    from enum import Enum, IntFlag

    def j(value: object) -> object:
        if isinstance(value, IntFlag):
            return "|".join(e.name for e in type(value) if e.name is not None and e.value and (value & e) == e) or "NONE"
        if isinstance(value, Enum):
            return value.name
        if isinstance(value, bool) or value is None or isinstance(value, (int, str)):
            return value
        if isinstance(value, float):
            return None if not math.isfinite(value) else value
        if isinstance(value, (bytes, bytearray, memoryview)):
            return bytes(value).hex()
        if isinstance(value, (tuple, list)):
            return [j(v) for v in value]
        return str(value)

    return {f.name: j(getattr(msg, f.name)) for f in dataclasses.fields(msg)}  # type: ignore[arg-type]


def test_fast_field_rendering_equals_the_reference_on_random_messages() -> None:
    """Every message kind, values in and far out of range, NaN and infinities, every flag combination:
    the same JSON object (and the same types: a bool stays a bool, an enum is its name)."""
    from hypothesis import given, settings

    from protocol.framelog import message_fields

    from support.message_strategies import any_message

    @settings(max_examples=500, deadline=None)
    @given(any_message)
    def check(msg: object) -> None:
        got, want = message_fields(msg), _fields_as_first_written(msg)
        assert json.dumps(got) == json.dumps(want)
        assert [type(v) for v in got.values()] == [type(v) for v in want.values()]

    check()


def test_flag_names_of_two_flag_classes_with_equal_values_stay_apart() -> None:
    """The rendering caches a flag value's names: ``A.X == B.Y`` (both 1) must not share an entry."""
    from enum import IntFlag

    from protocol.framelog import message_fields

    class A(IntFlag):
        X = 1

    class B(IntFlag):
        Y = 1

    @dataclasses.dataclass
    class Both:
        a: A
        b: B

    assert message_fields(Both(A.X, B.Y)) == {"a": "X", "b": "Y"}
    assert message_fields(Both(A(0), B.Y)) == {"a": "NONE", "b": "Y"}
