"""One typical instance of every message type (for tests, benchmarks and docs)."""

from __future__ import annotations

from protocol import messages as m
from protocol.messages import Message, MsgType

__all__ = ["SAMPLES", "servo_frame_12", "servo_frame_n", "telemetry_12", "telemetry_n"]


def servo_frame_n(n: int, apply_at_us: int = 1_234_567) -> m.ServoFrame:
    """A full SERVO_FRAME for a robot of ``n`` servos (the hot path host -> board)."""
    return m.ServoFrame(apply_at_us=apply_at_us, mask=(1 << n) - 1, targets=tuple(0.05 * i - 0.3 for i in range(n)))


def servo_frame_12(apply_at_us: int = 1_234_567) -> m.ServoFrame:
    """A full 12-servo SERVO_FRAME."""
    return servo_frame_n(12, apply_at_us)


def telemetry_12(board_time_us: int = 2_000_000) -> m.Telemetry:
    """A 12-servo TELEMETRY report."""
    return telemetry_n(12, board_time_us)


def telemetry_n(n: int, board_time_us: int = 2_000_000) -> m.Telemetry:
    """A TELEMETRY report of a robot of ``n`` servos (the hot path board -> host)."""
    return m.Telemetry(
        board_time_us=board_time_us,
        positions=tuple(0.1 * i - 0.6 for i in range(n)),
        velocities=tuple(0.5 - 0.1 * i for i in range(n)),
        efforts=tuple(0.01 * i for i in range(n)),
        imu_rpy=(0.01, -0.02, 1.5),
        faults=m.FaultFlags.CLAMPED,
        buffer_fill=4,
        last_applied_seq=321,
        late_count=1,
        dropped_count=0,
        link_errors=2,
    )


SAMPLES: dict[MsgType, Message] = {
    MsgType.HELLO: m.Hello(protocol_version=1, schema_hash=0xDEADBEEF, host_time_us=1_700_000_000_000_000),
    MsgType.CAPS: m.Caps(
        protocol_version=1,
        schema_hash=0xDEADBEEF,
        servo_count=12,
        control_rate_hz=500,
        buffer_depth=64,
        telemetry_rate_hz=50,
        board_time_us=123,
        lockstep=True,
        robot="quadruped",
        servo_table_hash=0x1234ABCD,
    ),
    MsgType.TIME_SYNC_REQUEST: m.TimeSyncRequest(t1_host_us=10),
    MsgType.TIME_SYNC_REPLY: m.TimeSyncReply(t1_host_us=10, t2_board_us=20, t3_board_us=25),
    MsgType.CONFIG: m.Config(key=m.ConfigKey.WATCHDOG_MS, value=200),
    MsgType.HEARTBEAT: m.Heartbeat(sender_time_us=5_000),
    MsgType.ADVANCE: m.Advance(until_us=20_000),
    MsgType.SERVO_FRAME: servo_frame_12(),
    MsgType.FLUSH: m.Flush(from_us=1_000_000, mask=0x0300),
    MsgType.ESTOP: m.Estop(),
    MsgType.ESTOP_CLEAR: m.EstopClear(),
    MsgType.TELEMETRY: telemetry_12(),
    MsgType.SIM_STATE: m.SimState(board_time_us=99, base_pos=(0.0, 0.25, 0.125), base_quat=(1.0, 0.0, 0.0, 0.0)),
    MsgType.ACK: m.Ack(ack_seq=7, msg_type=MsgType.SERVO_FRAME),
    MsgType.NACK: m.Nack(ack_seq=8, msg_type=MsgType.SERVO_FRAME, reason=m.NackReason.LATE, detail="late by 3 ms"),
    MsgType.SCREEN: m.ScreenCommand(target=m.ScreenTarget.EYES, name="blink", start_at_us=100, duration_ms=0),
    MsgType.SPEAKER: m.SpeakerCommand(
        action=m.SpeakerAction.PLAY,
        kind=m.SoundKind.SPEECH,
        start_at_us=100,
        duration_ms=1500,
        volume=80,
        text="Hello, I am a robot!",
    ),
    MsgType.CAMERA_CAPTURE: m.CameraCapture(request_id=3, width=160, height=120),
    MsgType.CAMERA_CHUNK: m.CameraChunk(request_id=3, index=0, total=2, data=b"\x89PNG\r\n\x1a\n" + bytes(20)),
    MsgType.CAMERA_RESEND: m.CameraResend(request_id=3, first=1, wanted=b"\x05"),
}
