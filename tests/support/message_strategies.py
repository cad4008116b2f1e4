"""Hypothesis strategies for every protocol message (values anywhere in range or far outside it),
shared by the codec and frame-log tests."""

from __future__ import annotations

from hypothesis import strategies as st

from protocol import codec
from protocol import messages as m
from protocol.messages import MAX_SERVOS, MsgType

__all__ = ["ANY_FLOAT", "ANY_INT", "ASCII", "FINITE_OR_INF", "STRATEGIES", "any_message", "clamp", "floats_list", "u"]


ANY_INT = st.integers(min_value=-(2**70), max_value=2**70)
ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True)
FINITE_OR_INF = st.floats(allow_nan=False, allow_infinity=True)
ASCII = st.characters(min_codepoint=0, max_codepoint=127)


def clamp(v: int, lo: int, hi: int) -> int:
    return min(max(int(v), lo), hi)


def u(bits: int):
    return lambda v: clamp(v, 0, 2**bits - 1)


def floats_list(n: int, elements=ANY_FLOAT):
    return st.lists(elements, min_size=n, max_size=n).map(tuple)


@st.composite
def servo_frames(draw):
    mask = draw(st.integers(0, 2**MAX_SERVOS - 1))
    targets = draw(floats_list(mask.bit_count(), FINITE_OR_INF))
    return m.ServoFrame(apply_at_us=draw(ANY_INT), mask=mask, targets=targets)


@st.composite
def telemetries(draw):
    n = st.integers(0, MAX_SERVOS)
    return m.Telemetry(
        board_time_us=draw(ANY_INT),
        positions=draw(n.flatmap(floats_list)),
        velocities=draw(n.flatmap(floats_list)),
        efforts=draw(n.flatmap(floats_list)),
        imu_rpy=draw(floats_list(3)),
        faults=m.FaultFlags(draw(st.integers(0, 0x3F))),
        buffer_fill=draw(ANY_INT),
        last_applied_seq=draw(ANY_INT),
        late_count=draw(ANY_INT),
        dropped_count=draw(ANY_INT),
        link_errors=draw(ANY_INT),
    )


@st.composite
def camera_chunks(draw):
    total = draw(st.integers(1, 2**16 - 1))
    return m.CameraChunk(
        request_id=draw(ANY_INT),
        index=draw(st.integers(0, total - 1)),
        total=total,
        data=draw(st.binary(max_size=codec.MAX_CHUNK_DATA)),
    )


STRATEGIES = {
    MsgType.HELLO: st.builds(m.Hello, ANY_INT, ANY_INT, ANY_INT),
    MsgType.CAPS: st.builds(m.Caps, ANY_INT, ANY_INT, ANY_INT, ANY_INT, ANY_INT, ANY_INT, ANY_INT, st.booleans()),
    MsgType.TIME_SYNC_REQUEST: st.builds(m.TimeSyncRequest, ANY_INT),
    MsgType.TIME_SYNC_REPLY: st.builds(m.TimeSyncReply, ANY_INT, ANY_INT, ANY_INT),
    MsgType.CONFIG: st.builds(m.Config, st.sampled_from(m.ConfigKey), ANY_INT),
    MsgType.HEARTBEAT: st.builds(m.Heartbeat, ANY_INT),
    MsgType.ADVANCE: st.builds(m.Advance, ANY_INT),
    MsgType.SERVO_FRAME: servo_frames(),
    MsgType.FLUSH: st.builds(m.Flush, ANY_INT, st.integers(0, 2**MAX_SERVOS - 1)),
    MsgType.ESTOP: st.just(m.Estop()),
    MsgType.ESTOP_CLEAR: st.just(m.EstopClear()),
    MsgType.TELEMETRY: telemetries(),
    MsgType.SIM_STATE: st.builds(m.SimState, ANY_INT, floats_list(3), floats_list(4)),
    MsgType.ACK: st.builds(m.Ack, ANY_INT, st.sampled_from(MsgType)),
    MsgType.NACK: st.builds(
        m.Nack,
        ANY_INT,
        st.sampled_from(MsgType),
        st.sampled_from(m.NackReason),
        st.text(ASCII, max_size=codec.MAX_NACK_DETAIL_BYTES),
    ),
    MsgType.SCREEN: st.builds(
        m.ScreenCommand, st.sampled_from(m.ScreenTarget), st.text(ASCII, max_size=24), ANY_INT, ANY_INT
    ),
    MsgType.SPEAKER: st.builds(
        m.SpeakerCommand,
        st.sampled_from(m.SpeakerAction),
        st.sampled_from(m.SoundKind),
        ANY_INT,
        ANY_INT,
        ANY_INT,
        st.text(ASCII, max_size=24),
        st.text(st.characters(codec="utf-8"), max_size=50).filter(lambda s: len(s.encode()) <= 200),
    ),
    MsgType.CAMERA_CAPTURE: st.builds(m.CameraCapture, ANY_INT, ANY_INT, ANY_INT),
    MsgType.CAMERA_CHUNK: camera_chunks(),
    MsgType.CAMERA_RESEND: st.builds(m.CameraResend, ANY_INT, ANY_INT, st.binary(max_size=codec.MAX_RESEND_BITMAP)),
}
assert set(STRATEGIES) == set(MsgType)

#: Every message type, values anywhere in range or far outside it (clamped on the wire).
any_message = st.one_of(*STRATEGIES.values())
