"""Payload codec: round trips with predicted quantisation, structural errors, schema hash."""

from __future__ import annotations

import dataclasses
import math
import os
import subprocess
import sys
from enum import IntEnum

import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol import codec
from protocol import messages as m
from protocol.codec import (
    LAYOUTS,
    MESSAGE_CLASSES,
    SCHEMA_HASH,
    PayloadError,
    compute_schema_hash,
    decode_payload,
    encode_payload,
    msg_type_of,
    quantize_effort,
    quantize_f32,
    quantize_message,
    quantize_position,
    quantize_velocity,
    unwrap_time_us,
)
from protocol.framing import Frame, FrameDecoder, encode_frame, frame_size
from protocol.messages import MAX_SERVOS, MsgType
from protocol.testing.samples import SAMPLES

# --- strategies and an independent prediction of what survives the wire ---------------------

from support.message_strategies import (  # noqa: E402  (shared with tests/protocol/test_framelog.py)
    ANY_FLOAT,
    ANY_INT,
    ASCII,
    FINITE_OR_INF,
    STRATEGIES,
    any_message,
    clamp,
    floats_list,
    u,
)

_q = {"pos": quantize_position, "vel": quantize_velocity, "eff": quantize_effort}


def predict(msg: m.Message) -> m.Message:
    """What the other end receives, by the documented rules (independent of the codec's code)."""
    r = dataclasses.replace
    u8, u16, u32, u64 = u(8), u(16), u(32), u(64)
    match msg:
        case m.Hello():
            return r(msg, protocol_version=u8(msg.protocol_version), schema_hash=u32(msg.schema_hash),
                     host_time_us=u64(msg.host_time_us))
        case m.Caps():
            return r(msg, protocol_version=u8(msg.protocol_version), schema_hash=u32(msg.schema_hash),
                     servo_count=u8(msg.servo_count), control_rate_hz=u16(msg.control_rate_hz),
                     buffer_depth=u16(msg.buffer_depth), telemetry_rate_hz=u16(msg.telemetry_rate_hz),
                     board_time_us=u64(msg.board_time_us))
        case m.TimeSyncRequest():
            return r(msg, t1_host_us=u64(msg.t1_host_us))
        case m.TimeSyncReply():
            return r(msg, t1_host_us=u64(msg.t1_host_us), t2_board_us=u64(msg.t2_board_us),
                     t3_board_us=u64(msg.t3_board_us))
        case m.Config():
            return r(msg, value=clamp(msg.value, -(2**31), 2**31 - 1))
        case m.Heartbeat():
            return r(msg, sender_time_us=u64(msg.sender_time_us))
        case m.Advance():
            return r(msg, until_us=u64(msg.until_us))
        case m.ServoFrame():
            return r(msg, apply_at_us=msg.apply_at_us % 2**32,
                     targets=tuple(quantize_position(x) for x in msg.targets))
        case m.Flush():
            return r(msg, from_us=u64(msg.from_us))
        case m.Telemetry():
            return r(msg, board_time_us=u64(msg.board_time_us),
                     positions=tuple(map(quantize_position, msg.positions)),
                     velocities=tuple(map(quantize_velocity, msg.velocities)),
                     efforts=tuple(map(quantize_effort, msg.efforts)),
                     imu_rpy=tuple(map(quantize_position, msg.imu_rpy)),
                     buffer_fill=u16(msg.buffer_fill), last_applied_seq=msg.last_applied_seq % 2**16,
                     late_count=u32(msg.late_count), dropped_count=u32(msg.dropped_count),
                     link_errors=u32(msg.link_errors))
        case m.SimState():
            return r(msg, board_time_us=u64(msg.board_time_us), base_pos=tuple(map(quantize_f32, msg.base_pos)),
                     base_quat=tuple(map(quantize_f32, msg.base_quat)))
        case m.Ack() | m.Nack():
            return r(msg, ack_seq=msg.ack_seq % 2**16)
        case m.ScreenCommand():
            return r(msg, start_at_us=u64(msg.start_at_us), duration_ms=u32(msg.duration_ms))
        case m.SpeakerCommand():
            return r(msg, start_at_us=u64(msg.start_at_us), duration_ms=u32(msg.duration_ms), volume=u8(msg.volume))
        case m.CameraCapture():
            return r(msg, request_id=u32(msg.request_id), width=u16(msg.width), height=u16(msg.height))
        case m.CameraChunk():
            return r(msg, request_id=u32(msg.request_id))
        case m.CameraResend():
            return r(msg, request_id=u32(msg.request_id), first=u16(msg.first))
    return msg


def norm(value):
    """Comparable form: NaN -> 'nan', tuples recursively, dataclasses by type and fields."""
    if dataclasses.is_dataclass(value):
        return (type(value).__name__, tuple((f.name, norm(getattr(value, f.name))) for f in dataclasses.fields(value)))
    if isinstance(value, (tuple, list)):
        return tuple(norm(v) for v in value)
    if isinstance(value, float) and math.isnan(value):
        return "nan"
    return value


# --- round trips ---------------------------------------------------------------------------


def test_every_type_has_a_sample_that_round_trips() -> None:
    assert set(SAMPLES) == set(MsgType)
    for t, msg in SAMPLES.items():
        assert msg_type_of(msg) is t
        back = decode_payload(t, encode_payload(msg))
        assert norm(back) == norm(predict(msg)), t.name


@given(any_message)
def test_payload_round_trip_matches_prediction(msg: m.Message) -> None:
    t = msg_type_of(msg)
    back = decode_payload(t, encode_payload(msg))
    assert type(back) is type(msg)
    assert norm(back) == norm(predict(msg))
    assert norm(codec.quantize_message(msg)) == norm(back)
    # quantisation is idempotent: what arrived survives another trip unchanged
    assert norm(decode_payload(t, encode_payload(back))) == norm(back)


@given(any_message, st.integers(-(2**20), 2**20))
def test_frame_round_trip_of_every_type(msg: m.Message, seq: int) -> None:
    wire = encode_frame(msg, seq)
    assert wire.endswith(b"\x00") and b"\x00" not in wire[:-1]
    assert len(wire) == frame_size(msg) or len(wire) > 254
    dec = FrameDecoder()
    items = dec.feed(wire)
    assert len(items) == 1 and isinstance(items[0], Frame), items
    frame = items[0]
    assert frame.seq == seq % 2**16
    assert frame.msg_type is msg_type_of(msg)
    assert frame.raw == wire
    assert norm(frame.msg) == norm(predict(msg))
    assert dec.frames_ok == 1 and dec.error_count == 0 and dec.pending == 0


def test_quantisation_helpers() -> None:
    assert quantize_position(0.12344) == 0.1234
    assert quantize_position(0.12346) == 0.1235
    assert quantize_position(4.0) == 3.2767
    assert quantize_position(-math.inf) == -3.2767
    assert math.isnan(quantize_position(math.nan))
    assert quantize_velocity(8.00049) == 8.0
    assert quantize_velocity(100.0) == 32.767
    assert quantize_effort(-0.0014) == -0.001
    assert quantize_f32(0.1) != 0.1 and abs(quantize_f32(0.1) - 0.1) < 1e-8
    assert quantize_f32(1e300) == pytest.approx(3.4028234663852886e38)
    assert codec.quantize_apply_at(2**32 + 7) == 7
    assert codec.quantize_apply_at(-1) == 2**32 - 1


@given(st.floats(min_value=-3.2767, max_value=3.2767))
def test_position_error_is_at_most_half_a_step(x: float) -> None:
    assert abs(quantize_position(x) - x) <= 0.5e-4 + 1e-12


@given(st.integers(0, 2**62), st.integers(-(2**31) + 1, 2**31 - 1))
def test_unwrap_recovers_times_within_half_the_wrap(ref: int, delta: int) -> None:
    true = max(0, ref + delta)
    assert unwrap_time_us(true & 0xFFFF_FFFF, ref) == true


def test_unwrap_across_the_wrap() -> None:
    ref = 2**32 - 1000
    assert unwrap_time_us(500, ref) == 2**32 + 500
    assert unwrap_time_us(2**32 - 2000, 2**32 + 10) == 2**32 - 2000


# --- structural errors at encode time --------------------------------------------------------


@pytest.mark.parametrize(
    ("msg", "needle"),
    [
        (m.ServoFrame(0, 1 << MAX_SERVOS, (0.0,)), "outside"),
        (m.ServoFrame(0, -1, ()), "outside"),
        (m.ServoFrame(0, 0b111, (0.0, 0.0)), "popcount"),
        (m.ServoFrame(0, 0b1, (math.nan,)), "NaN"),
        (m.ServoFrame(0, 0b1, ("x",)), "number"),
        (m.Flush(0, 1 << 20), "outside"),
        (m.Telemetry(0, (0.0,) * 17, (), (), (0.0, 0.0, 0.0), m.FaultFlags.NONE, 0, 0, 0, 0, 0), "at most 16"),
        (m.Telemetry(0, (), (), (), (0.0, 0.0), m.FaultFlags.NONE, 0, 0, 0, 0, 0), "fixed"),
        (m.Nack(0, MsgType.ACK, m.NackReason.BUSY, "x" * 65), "at most 64"),
        (m.ScreenCommand(m.ScreenTarget.FACE, "smile" * 7, 0, 0), "at most 32"),
        (m.ScreenCommand(m.ScreenTarget.FACE, "生日快乐歌生日快乐歌生", 0, 0), "33 bytes, at most 32"),
        (m.SpeakerCommand(m.SpeakerAction.PLAY, m.SoundKind.SPEECH, 0, 0, 50, text="é" * 101), "at most 200"),
        (m.Config(99, 1), "not a ConfigKey"),  # type: ignore[arg-type]
        (m.Ack(0, 0x7F), "not a MsgType"),  # type: ignore[arg-type]
        (m.CameraChunk(1, 2, 2, b""), "not below total"),
        (m.CameraChunk(1, 0, 1, bytes(codec.MAX_CHUNK_DATA + 1)), "at most"),
        (m.SimState(0, (0.0, 0.0), (1.0, 0.0, 0.0, 0.0)), "expected 3"),
    ],
)
def test_structurally_invalid_messages_raise_clear_errors(msg: m.Message, needle: str) -> None:
    with pytest.raises(PayloadError, match=needle) as info:
        encode_payload(msg)
    assert isinstance(info.value, ValueError)
    assert msg_type_of(msg).name in str(info.value)


def test_not_a_message() -> None:
    with pytest.raises(PayloadError, match="not a protocol message"):
        encode_payload(object())  # type: ignore[arg-type]


# --- bad payloads at decode time ---------------------------------------------------------------


@pytest.mark.parametrize("t", list(MsgType), ids=lambda t: t.name)
def test_truncated_and_padded_payloads_raise_payload_error(t: MsgType) -> None:
    payload = encode_payload(SAMPLES[t])
    for cut in range(len(payload)):
        if (t is MsgType.CAMERA_CHUNK and cut >= 8) or (t is MsgType.CAMERA_RESEND and cut >= 6):
            continue  # the chunk data / bitmap is "the rest of the payload": shorter is still valid
        with pytest.raises(PayloadError):
            decode_payload(t, payload[:cut])
    if t not in (MsgType.CAMERA_CHUNK, MsgType.CAMERA_RESEND):
        with pytest.raises(PayloadError, match="trailing"):
            decode_payload(t, payload + b"\x00")


@pytest.mark.parametrize(
    ("t", "payload", "needle"),
    [
        (MsgType.SERVO_FRAME, b"\x00\x00\x00\x00" + b"\x01\x00" + b"\x00\x80", "NaN"),
        (MsgType.CONFIG, b"\x63" + bytes(4), "unknown ConfigKey"),
        (MsgType.ACK, b"\x00\x00\x7f", "unknown MsgType"),
        (MsgType.CAPS, bytes(20) + b"\x02", "0 or 1"),
        (MsgType.NACK, b"\x00\x00\x10\x01\x41" + b"x" * 65, "exceeds 64"),
        (MsgType.SCREEN, b"\x00\x01\xff" + bytes(12), "not valid utf-8"),
        (MsgType.CAMERA_CHUNK, bytes(4) + b"\x02\x00\x02\x00", "not below total"),
        (MsgType.TELEMETRY, bytes(8) + b"\x11", "exceeds 16"),
    ],
)
def test_bad_payload_values(t: MsgType, payload: bytes, needle: str) -> None:
    with pytest.raises(PayloadError, match=needle):
        decode_payload(t, payload)


@given(st.sampled_from(MsgType), st.binary(max_size=300))
def test_decode_of_random_bytes_only_raises_payload_error(t: MsgType, payload: bytes) -> None:
    try:
        msg = decode_payload(t, payload)
    except PayloadError:
        return
    assert msg_type_of(msg) is t


def test_unknown_type_value() -> None:
    with pytest.raises(PayloadError, match="unknown message type"):
        decode_payload(0x7F, b"")  # type: ignore[arg-type]


# --- schema hash ---------------------------------------------------------------------------

#: Pinned so that a schema change is a conscious act: update this value together with
#: protocol/messages.py or protocol/codec.py (old boards will then refuse the new host).
PINNED_SCHEMA_HASH = 0x1D7AD3A3  # FaultFlags.SERVO_FAULT + NackReason.SERVO_FAULT (the C firmware's servo bus)


def test_schema_hash_is_u32_and_pinned() -> None:
    assert 0 <= SCHEMA_HASH < 2**32
    assert compute_schema_hash() == SCHEMA_HASH
    assert SCHEMA_HASH == PINNED_SCHEMA_HASH, (
        f"schema changed: SCHEMA_HASH is now {SCHEMA_HASH:#010x}; update PINNED_SCHEMA_HASH if intended"
    )


def test_schema_hash_is_the_same_in_other_processes() -> None:
    code = "from protocol.codec import SCHEMA_HASH; print(SCHEMA_HASH)"
    for seed in ("0", "12345"):
        env = dict(os.environ, PYTHONHASHSEED=seed)
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
        assert int(out.stdout) == SCHEMA_HASH


def test_schema_hash_changes_with_the_schema() -> None:
    base = {t: list(fields) for t, fields in LAYOUTS.items()}
    seen = {compute_schema_hash(base)}

    def check(layouts=None, classes=None) -> None:
        h = compute_schema_hash(layouts if layouts is not None else base, classes)
        assert h not in seen
        seen.add(h)

    # a wire format: positions at a different scale
    changed = dict(base)
    changed[MsgType.SERVO_FRAME] = [
        ("apply_at_us", LAYOUTS[MsgType.SERVO_FRAME][0][1]),
        ("mask", LAYOUTS[MsgType.SERVO_FRAME][1][1]),
        ("targets", codec.Q16Array(1000, mask_field="mask", allow_nan=False)),
    ]
    check(changed)
    # a wider field
    changed = dict(base)
    changed[MsgType.HEARTBEAT] = [("sender_time_us", codec.UInt(4))]
    check(changed)
    # a field name
    changed = dict(base)
    changed[MsgType.ADVANCE] = [("until_board_us", codec.UInt(8))]
    check(changed)
    # a field's Python type
    Adv = dataclasses.make_dataclass("Advance", [("until_us", "float")], frozen=True)
    check(None, {**MESSAGE_CLASSES, MsgType.ADVANCE: Adv})
    # a message type number
    Renumbered = IntEnum("MsgType", {t.name: (0x40 if t is MsgType.ESTOP else int(t)) for t in MsgType})
    layouts = {Renumbered[t.name]: f for t, f in base.items()}
    classes = {Renumbered[t.name]: c for t, c in MESSAGE_CLASSES.items()}
    check(layouts, classes)
    # an enum member's value inside a field
    Reason = IntEnum("NackReason", {r.name: int(r) + (1 if r is m.NackReason.BUSY else 0) for r in m.NackReason})
    changed = dict(base)
    changed[MsgType.NACK] = [(n, codec.EnumU8(Reason) if n == "reason" else f) for n, f in base[MsgType.NACK]]
    check(changed)


def test_numpy_values_are_accepted() -> None:
    np = pytest.importorskip("numpy")
    msg = m.ServoFrame(apply_at_us=np.int64(5), mask=np.uint16(0b101), targets=np.array([0.1, 7.0]))
    assert quantize_message(msg) == m.ServoFrame(apply_at_us=5, mask=0b101, targets=(0.1, 3.2767))
    caps = codec.quantize_message(SAMPLES[MsgType.CAPS].__class__(**{
        **dataclasses.asdict(SAMPLES[MsgType.CAPS]), "lockstep": np.bool_(True), "servo_count": np.int32(12)}))
    assert caps.lockstep is True and caps.servo_count == 12


@pytest.mark.parametrize("bad", [None, "12", math.nan])
def test_non_numbers_in_integer_fields_are_clear_errors(bad) -> None:
    with pytest.raises(PayloadError, match="HEARTBEAT: sender_time_us"):
        encode_payload(m.Heartbeat(sender_time_us=bad))


def test_names_on_the_wire_are_utf8_in_any_language() -> None:
    for name in ("café", "生日快乐", "Ünïcödé ☀"):
        for msg in (m.ScreenCommand(m.ScreenTarget.FACE, name, 5, 6),
                    m.SpeakerCommand(m.SpeakerAction.PLAY, m.SoundKind.CLIP, 0, 1000, 60, name=name)):
            assert decode_payload(msg_type_of(msg), encode_payload(msg)) == msg
