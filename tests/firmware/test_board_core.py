"""Board core in lockstep (no I/O): timing, interpolation, clamps, rejections, safety, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest

from firmware_sim.board import Board
from firmware_sim.config import BoardConfig, ConfigError
from firmware_sim.safety import Mode
from protocol.codec import SCHEMA_HASH
from protocol.framing import encode_frame
from protocol.messages import (
    Ack,
    Advance,
    Config,
    ConfigKey,
    Estop,
    EstopClear,
    FaultFlags,
    Flush,
    Heartbeat,
    Hello,
    Nack,
    NackReason,
    ServoFrame,
    SimState,
    Telemetry,
    TimeSyncReply,
    TimeSyncRequest,
)
from robots.coco import load_poses, load_servo_table

from .conftest import make_board, run

HEAD_YAW = 8  # servo id 9
FR_KNEE = 1  # servo id 2
TABLE = load_servo_table()
NEUTRAL = TABLE.neutral


def frame(t_us: int, values: dict[int, float]) -> ServoFrame:
    idx = sorted(values)
    return ServoFrame(t_us, sum(1 << i for i in idx), tuple(values[i] for i in idx))


def full(t_us: int, q) -> ServoFrame:  # type: ignore[no-untyped-def]
    return ServoFrame(t_us, 0x0FFF, tuple(float(v) for v in q))


def test_config_validation() -> None:
    with pytest.raises(ConfigError, match="whole multiple of dt"):
        BoardConfig(rate_hz=500, dt=0.003).validate()
    with pytest.raises(ConfigError, match="telemetry"):
        BoardConfig(telemetry_rate_hz=1000).validate()
    assert BoardConfig(rate_hz=250, dt=0.002).validate().substeps == 2


def test_frame_applied_exactly_at_its_tick(board: Board) -> None:
    assert not board.can_tick()  # nothing covered yet: lockstep waits
    assert board.handle(frame(10_000, {HEAD_YAW: 0.01}), seq=5) == []
    ticks_before = 0
    while board.now_us < 10_000:
        board.tick()
        ticks_before += 1
        assert board.last_applied_seq == 0 and len(board.buffer) == 1
    assert ticks_before == 5 and board.can_tick()
    board.tick()  # the tick at t = 10 ms applies it
    assert board.last_applied_seq == 5 and len(board.buffer) == 0
    assert board.desired[HEAD_YAW] == 0.01
    assert not board.can_tick()  # covered only up to the frame's apply-at
    board.handle(Advance(20_000), seq=6)
    run(board)
    assert board.now_us == 20_000


def test_interpolation_between_frames_partial_mask(board: Board) -> None:
    board.handle(frame(100_000, {HEAD_YAW: 0.2}), 1)
    board.handle(frame(200_000, {HEAD_YAW: 0.4, FR_KNEE: 0.5}), 2)
    seen: dict[int, np.ndarray] = {}
    while board.can_tick():
        t = board.now_us
        board.tick()
        seen[t] = board.desired.copy()
    # first segment from where the servo was at t=0 (neutral) to the first keyframe
    assert seen[50_000][HEAD_YAW] == pytest.approx(0.1)
    assert seen[100_000][HEAD_YAW] == pytest.approx(0.2)
    assert seen[150_000][HEAD_YAW] == pytest.approx(0.3)
    assert seen[176_000][HEAD_YAW] == pytest.approx(0.2 + 0.2 * 0.76)
    assert seen[200_000][HEAD_YAW] == pytest.approx(0.4)
    # the knee only has the second keyframe: it interpolates from neutral over 0..200 ms
    assert seen[100_000][FR_KNEE] == pytest.approx(NEUTRAL[FR_KNEE] + (0.5 - NEUTRAL[FR_KNEE]) * 0.5)
    # servos without frames hold neutral
    assert seen[150_000][0] == pytest.approx(NEUTRAL[0])


def test_frames_out_of_order_are_applied_by_time(board: Board) -> None:
    board.handle(frame(40_000, {HEAD_YAW: 0.04}), 2)
    board.handle(frame(20_000, {HEAD_YAW: 0.02}), 1)
    applied = []
    while board.can_tick():
        board.tick()
        applied.append(board.last_applied_seq)
    assert applied.index(1) == 10 and applied.index(2) == 20


def test_limit_and_speed_clamps(board: Board) -> None:
    board.handle(frame(10_000, {FR_KNEE: 3.0, HEAD_YAW: 1.5}), 1)
    cmds = []
    tel: list[Telemetry] = []
    board.handle(Advance(400_000), 2)
    while board.can_tick():
        tel += [m for m in board.tick() if isinstance(m, Telemetry)]
        cmds.append(board.servo.cmd.copy())
    cmds_a = np.array(cmds)
    assert cmds_a[:, FR_KNEE].max() <= TABLE[FR_KNEE].max + 1e-12
    assert cmds_a[-1, FR_KNEE] == pytest.approx(TABLE[FR_KNEE].max)
    step = np.abs(np.diff(cmds_a[:, HEAD_YAW])).max()
    assert step <= TABLE[HEAD_YAW].max_speed * 0.002 + 1e-12
    assert board.servo.limit_clamps > 0 and board.servo.speed_clamps > 0
    assert tel[0].faults & FaultFlags.CLAMPED
    assert not tel[-1].faults & FaultFlags.CLAMPED  # flag covers "since the last report" only
    # ctrl is on the encoder grid, or the measured position inside the deadband (no drive)
    res = TABLE.model.resolution
    measured = board.positions()
    for i in range(12):
        on_grid = abs(board.ctrl[i] / res - round(board.ctrl[i] / res)) < 1e-6
        assert on_grid or abs(board.ctrl[i] - measured[i]) < TABLE.model.deadband


def test_late_and_future_frames_rejected_and_counted(board: Board) -> None:
    board.handle(Advance(100_000), 1)
    run(board)
    (nack,) = board.handle(frame(50_000, {HEAD_YAW: 0.1}), 2)
    assert isinstance(nack, Nack) and nack.reason is NackReason.LATE and nack.ack_seq == 2
    (nack,) = board.handle(frame(board.now_us + 6_000_000, {HEAD_YAW: 0.1}), 3)
    assert nack.reason is NackReason.TOO_FAR_FUTURE
    assert board.handle(frame(board.now_us - 10_000, {HEAD_YAW: 0.1}), 4) == []  # within tolerance
    tel = board.telemetry()
    assert (tel.late_count, tel.dropped_count) == (1, 1)
    (nack,) = board.handle(ServoFrame(200_000, 1 << 13, (0.1,)), 5)
    assert nack.reason is NackReason.BAD_VALUE


def test_buffer_full_is_refused() -> None:
    b = make_board(buffer_depth=4)
    for k in range(4):
        assert b.handle(frame(10_000 * (k + 1), {HEAD_YAW: 0.0}), k) == []
    (nack,) = b.handle(frame(50_000, {HEAD_YAW: 0.0}), 9)
    assert nack.reason is NackReason.BUFFER_FULL and b.telemetry().dropped_count == 1


def test_flush_drops_future_frames_for_a_group(board: Board) -> None:
    board.handle(frame(20_000, {HEAD_YAW: 0.05, FR_KNEE: 0.4}), 1)
    board.handle(frame(40_000, {HEAD_YAW: 0.1, FR_KNEE: 0.5}), 2)
    (ack,) = board.handle(Flush(30_000, 1 << HEAD_YAW), 3)
    assert isinstance(ack, Ack)
    assert board.buffer.next_for(HEAD_YAW) == (20_000, 0.05)
    run(board)
    assert board.desired[HEAD_YAW] == pytest.approx(0.05) and board.desired[FR_KNEE] == pytest.approx(0.5)


def test_watchdog_hold_then_crouch_then_latched_fault(board: Board) -> None:
    board.handle(Advance(2_000_000), 1)  # the host goes silent for 2 s of board time
    modes: dict[int, Mode] = {}
    faults: list[tuple[int, FaultFlags]] = []
    while board.can_tick():
        t = board.now_us
        out = board.tick()
        modes[t] = board.mode
        faults += [(m.board_time_us, m.faults) for m in out if isinstance(m, Telemetry)]
    assert modes[200_000] is Mode.RUN and modes[202_000] is Mode.HOLD
    assert modes[1_200_000] is Mode.HOLD and modes[1_202_000] is Mode.CROUCH
    assert any(f & FaultFlags.WATCHDOG_HOLD for _, f in faults)
    assert faults[-1][1] & FaultFlags.WATCHDOG_FAULT
    # crouching: knees bend toward the crouch pose
    crouch = load_poses()["crouch"]
    assert board.servo.cmd[FR_KNEE] == pytest.approx(crouch[FR_KNEE], abs=1e-9)
    # latched: a heartbeat does not clear it and frames are refused
    assert board.handle(Heartbeat(0), 2) == []
    (nack,) = board.handle(frame(board.now_us + 10_000, {HEAD_YAW: 0.0}), 3)
    assert nack.reason is NackReason.FAULT_LATCHED
    board.handle(Advance(board.now_us + 10_000), 4)
    run(board)
    assert board.mode is Mode.CROUCH
    (ack,) = board.handle(EstopClear(), 5)
    assert isinstance(ack, Ack) and board.mode is Mode.RUN
    assert board.handle(frame(board.now_us + 10_000, {HEAD_YAW: 0.0}), 6) == []


def test_message_during_hold_resumes(board: Board) -> None:
    board.handle(Advance(400_000), 1)
    run(board)
    assert board.mode is Mode.HOLD
    board.handle(Heartbeat(0), 2)
    assert board.mode is Mode.RUN


def test_lockstep_frames_feed_the_watchdog(board: Board) -> None:
    """A long trajectory sent at once is not a silent link: applied frames feed the watchdog."""
    for k in range(1, 101):
        board.handle(frame(k * 10_000, {HEAD_YAW: 0.001 * k}), k)
    run(board)
    assert board.now_us == 1_002_000 and board.mode is Mode.RUN


def test_estop_within_one_tick(board: Board) -> None:
    for k in range(1, 51):
        board.handle(frame(k * 10_000, {HEAD_YAW: 0.02 * k}), k)
    board.handle(Advance(200_000), 99)
    while board.now_us < 200_000:
        board.tick()
    moving = board.data.qvel[board.cm.dof_adr[HEAD_YAW]]
    assert abs(moving) > 0.5
    at_estop = board.positions()
    (ack,) = board.handle(Estop(), 100)
    assert isinstance(ack, Ack)
    board.tick()
    expected = board.servo.quantise(at_estop)  # hold where it was, on the encoder grid
    assert np.abs(board.ctrl - expected).max() <= TABLE.model.deadband + 1e-9
    assert abs(board.ctrl[HEAD_YAW] - at_estop[HEAD_YAW]) < 0.01  # not where the trajectory was going
    assert len(board.buffer) == 0 and board.mode is Mode.ESTOP
    assert board.telemetry().faults & FaultFlags.ESTOP
    (nack,) = board.handle(frame(board.now_us + 10_000, {HEAD_YAW: 0.0}), 101)
    assert nack.reason is NackReason.ESTOPPED
    board.handle(Advance(board.now_us + 300_000), 102)
    run(board)
    assert abs(board.data.qvel[board.cm.dof_adr[HEAD_YAW]]) < 0.05  # stopped, holding
    assert abs(board.positions()[HEAD_YAW] - at_estop[HEAD_YAW]) < 0.1
    assert isinstance(board.handle(EstopClear(), 103)[0], Ack) and board.mode is Mode.RUN


def _stream() -> list[ServoFrame]:
    """0.6 s of a leg/head wiggle at 50 Hz."""
    frames = []
    for k in range(1, 31):
        t = k * 20_000
        q = list(NEUTRAL)
        s = math.sin(2 * math.pi * t / 600_000)
        q[0] += 0.3 * s
        q[1] += 0.2 * s
        q[HEAD_YAW] += 0.5 * s
        frames.append(full(t, q))
    return frames


def _telemetry_bytes(interleave: bool) -> tuple[list[bytes], list[tuple[float, ...]]]:
    b = make_board()
    out = []
    for k, f in enumerate(_stream()):
        b.handle(f, k + 1)
        if interleave:
            out += run(b)
    out += run(b)
    tel = [m for m in out if isinstance(m, Telemetry)]
    return [encode_frame(m, i) for i, m in enumerate(tel)], [m.positions for m in tel]


def test_lockstep_determinism_bit_for_bit() -> None:
    a, pos_a = _telemetry_bytes(interleave=False)
    b, _ = _telemetry_bytes(interleave=False)
    assert len(a) == 30 and a == b
    c, pos_c = _telemetry_bytes(interleave=True)
    d, _ = _telemetry_bytes(interleave=True)
    assert c == d
    assert pos_a == pos_c  # frames by apply-at time: how they were chunked does not matter to the physics


@pytest.mark.parametrize("name", ["stand", "sit", "crouch"])
def test_named_pose_is_reached(name: str) -> None:
    b = make_board()
    target = np.array(load_poses()[name])
    start = np.array(NEUTRAL)
    for k in range(1, 51):  # 1 s smooth (cosine) trajectory at 50 Hz
        s = 0.5 - 0.5 * math.cos(math.pi * k / 50)
        b.handle(full(k * 20_000, start + (target - start) * s), k)
    b.handle(Advance(1_500_000), 99)
    out = run(b)
    tel = [m for m in out if isinstance(m, Telemetry)][-1]
    err = np.degrees(np.abs(np.array(tel.positions) - target)).max()
    assert err < 3.0, f"{name}: largest error {err:.2f} deg"
    st = [m for m in out if isinstance(m, SimState)][-1]
    assert st.base_pos[2] > 0.03  # still on its feet (not collapsed)


def test_handshake_errors_timesync_config() -> None:
    b = Board(BoardConfig(lockstep=True))
    (n,) = b.handle(Hello(2, SCHEMA_HASH, 0), 3)
    assert n.reason is NackReason.VERSION_MISMATCH and "v2" in n.detail
    (n,) = b.handle(Hello(1, 0xDEADBEEF, 0), 4)
    assert n.reason is NackReason.SCHEMA_MISMATCH and "0xdeadbeef" in n.detail
    (r,) = b.handle(TimeSyncRequest(777), 5)
    assert isinstance(r, TimeSyncReply) and r.t1_host_us == 777 and r.t2_board_us == r.t3_board_us == 0
    (a,) = b.handle(Config(ConfigKey.TELEMETRY_RATE_HZ, 100), 6)
    assert isinstance(a, Ack) and b.cfg.telemetry_every == 5
    (n,) = b.handle(Config(ConfigKey.WATCHDOG_MS, -5), 7)
    assert n.reason is NackReason.BAD_VALUE
    (n,) = b.handle(b.telemetry(), 8)
    assert n.reason is NackReason.UNSUPPORTED
    rt = Board(BoardConfig())
    (n,) = rt.handle(Advance(10), 9)
    assert n.reason is NackReason.NOT_LOCKSTEP


def test_link_errors_counted() -> None:
    b = make_board()
    b.on_link_error()
    tel = b.telemetry()
    assert tel.link_errors == 1 and tel.faults & FaultFlags.LINK_ERRORS
    assert not b.telemetry().faults & FaultFlags.LINK_ERRORS


def test_a_frame_that_arrives_after_its_due_time_is_applied_at_the_next_tick(board: Board) -> None:
    """What a realtime start counts on (``FrameStreamer.start_due_us`` plans for a quick arrival, not a
    sure one): a frame up to ``max_late_us`` late takes effect at the first tick after it arrives,
    anchored at its due time, and is not counted as late."""
    board.handle(Advance(100_000), 1)
    run(board)
    now = board.now_us
    assert board.handle(frame(now - 1_000, {HEAD_YAW: 0.2}), 2) == []
    assert board.buffer.next_for(HEAD_YAW) == (now - 1_000, 0.2)
    board.handle(Advance(now + board.tick_us), 3)
    board.tick()
    assert board.buffer.next_for(HEAD_YAW) is None  # left the buffer at this tick
    assert (int(board.anchor_t[HEAD_YAW]), float(board.anchor_v[HEAD_YAW])) == (now - 1_000, 0.2)
    assert board.telemetry().late_count == 0


def test_each_message_type_has_one_sender_and_the_board_handles_exactly_the_hosts() -> None:
    """``protocol.messages.HOST_TO_BOARD`` / ``BOARD_TO_HOST`` split the types; the board's handler table
    covers exactly the host's, and refuses every board-sent one (``HOST_BOUND``, derived from them)."""
    from firmware_sim.board import HOST_BOUND
    from protocol.codec import MESSAGE_CLASSES
    from protocol.messages import BOARD_TO_HOST, HOST_TO_BOARD, MsgType

    assert HOST_TO_BOARD | BOARD_TO_HOST == set(MsgType) and not HOST_TO_BOARD & BOARD_TO_HOST
    assert set(Board._HANDLERS) == {MESSAGE_CLASSES[t] for t in HOST_TO_BOARD}
    assert set(HOST_BOUND) == {MESSAGE_CLASSES[t] for t in BOARD_TO_HOST}


def test_a_camera_chunk_from_the_host_is_refused_before_it_counts_as_traffic() -> None:
    """CAMERA_CHUNK is board-sent; the board's hand-written list of such types had left it out, so one
    from the host fed the sequence-gap counter before it was refused."""
    from protocol.messages import CameraChunk

    b = Board(BoardConfig(lockstep=True))
    received = b.rx_gaps.received
    (n,) = b.handle(CameraChunk(request_id=1, index=0, total=1, data=b"x"), 9)
    assert n.reason is NackReason.UNSUPPORTED
    assert b.rx_gaps.received == received
