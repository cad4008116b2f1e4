"""A servo that stops answering on the bus: the C firmware reports it (SERVO_FAULT in telemetry and
one NACK SERVO_FAULT naming it), refuses motion, holds every servo, and the host turns it into one
line. ESTOP_CLEAR tries the servo again; still silent, the fault latches anew."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

from host.link.faultcheck import servo_fault_message
from protocol.codec import SCHEMA_HASH
from protocol.messages import (
    PROTOCOL_VERSION, Advance, EstopClear, FaultFlags, Hello, Nack, NackReason, ServoFrame, Telemetry,
)
from robots.registry import load_robot

from .wire import Wire

ROBOT = load_robot("coco")
N = ROBOT.servo_count
DEAD = ROBOT.servos[2]  # id 3


def test_dead_servo_is_reported_and_the_others_hold(tmp_path: Path) -> None:
    w = Wire(["--lockstep", "--firmware", "c", "--asan", "--dead-servo", f"{DEAD.id}@0.3"], tmp_path / "board.stderr")
    try:
        w.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0))
        mask = (1 << N) - 1
        q = ROBOT.pose(ROBOT.start_pose)
        for k in range(1, 41):  # 0.4 s of frames: the servo dies at 0.3 s
            w.send(ServoFrame(10_000 * k, mask, q))
        w.send(Advance(1_000_000))
        w.wait(lambda: any(t.board_time_us >= 1_000_000 for t in w.of(Telemetry)), what="1 s of telemetry")
        tel = w.of(Telemetry)
        faulted = [t for t in tel if t.faults & FaultFlags.SERVO_FAULT]
        assert faulted and not tel[0].faults & FaultFlags.SERVO_FAULT
        first = faulted[0].board_time_us
        assert 300_000 <= first <= 300_000 + 4 * 20_000  # a few telemetry periods of silence
        nacks = [n for n in w.of(Nack) if n.reason == NackReason.SERVO_FAULT]
        assert nacks and f"servo id {DEAD.id} ({DEAD.name})" in nacks[0].detail
        # every servo holds once the fault latched: after the body settled, nothing moves
        held = [t.positions for t in tel if t.board_time_us > first + 300_000]
        assert len(held) >= 10
        for i in range(N):
            assert max(p[i] for p in held) - min(p[i] for p in held) < 0.01, i
        # frames are refused while the fault is latched
        seq = w.send(ServoFrame(1_020_000, mask, q))
        w.wait(lambda: any(n.ack_seq == seq for n in w.of(Nack)), what="the refusal")
        assert next(n for n in w.of(Nack) if n.ack_seq == seq).reason == NackReason.SERVO_FAULT
        # the host's one line names the servo and the way out
        client = SimpleNamespace(servo_fault=nacks[0], link_spec="pty")
        line = servo_fault_message(client, first)  # type: ignore[arg-type]
        assert f"servo id {DEAD.id} ({DEAD.name})" in line and "ghostshell estop --link pty --clear" in line
        assert "\n" not in line
        # ESTOP_CLEAR tries again; the servo is still silent, so the fault comes back
        w.send(EstopClear())
        w.send(Advance(1_600_000))
        w.wait(lambda: any(t.board_time_us >= 1_600_000 for t in w.of(Telemetry)), what="telemetry after the clear")
        after = [t for t in w.of(Telemetry) if t.board_time_us > 1_000_000]
        assert any(not t.faults & FaultFlags.SERVO_FAULT for t in after)
        assert after[-1].faults & FaultFlags.SERVO_FAULT
    finally:
        assert w.close() == 130  # stopped cleanly by its SIGTERM: "interrupted"
    err = (tmp_path / "board.stderr").read_text()
    assert f"board: servo id {DEAD.id} ({DEAD.name}) stopped answering on the servo bus" in err
