"""The C firmware on a servo bus of either protocol (Feetech STS, Dynamixel Protocol 2.0), over a real tty as a
USB adapter appears, with the hardware-safety behaviour a real robot needs.

The native firmware (ASan/UBSan build) is run directly: ``gs_firmware --bus tty:PATH:BAUD --protocol P``.
The plant is either ``python -m firmware_sim.plant --protocol P --baud N --lockstep`` as a subprocess (it
prints ``plant: servo bus on /dev/pts/N``), or the same :func:`firmware_sim.plant.server.serve` loop in a
thread of this process when a test reads the servos' state (torque, goals) from the plant itself. Lockstep:
the world steps once per goal SYNC WRITE, so nothing here waits on wall-clock time: every wait is for a
condition (telemetry at a board time, a state of the plant), with a timeout only as a failure bound.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import serial

from firmware_sim.cfirmware.build import build
from firmware_sim.cfirmware.servo_table import STEP_CENTRE
from firmware_sim.plant.bus import PlantBus
from firmware_sim.plant.conditions import Conditions, ServoError
from firmware_sim.plant.server import serve, set_line_speed
from firmware_sim.plant.servo import Fault
from firmware_sim.plant.world import World
from firmware_sim.transports.ports import PtyPort
from protocol.codec import SCHEMA_HASH
from protocol.framing import DecodeError, Frame, FrameDecoder, encode_frame
from protocol.messages import (
    PROTOCOL_VERSION, Advance, Caps, Estop, EstopClear, FaultFlags, Hello, Message, Nack, NackReason, ServoFrame,
    Telemetry,
)
from robots.registry import load_robot

ROBOT = load_robot("coco")
N = ROBOT.servo_count
MASK = (1 << N) - 1
ROOT = Path(__file__).resolve().parents[2]
WAIT_S = 60.0  # a failure bound, never a pacing


def _exe() -> Path:
    return build("native-asan", ROBOT)


def _step_range(i: int) -> tuple[int, int]:
    from robots.hardware import ServoCalibration, step_limits

    s = ROBOT.servos[i]
    return step_limits(s, ServoCalibration(s.id), ROBOT.servos.model.resolution)


def _steps(i: int, q: float) -> int:
    s = ROBOT.servos[i]
    return STEP_CENTRE + s.direction * round((q - s.neutral) / ROBOT.servos.model.resolution)


class NativeBoard:
    """``gs_firmware`` started directly, spoken to over its host pty (raw frames, as tests/cfirmware/wire.py)."""

    def __init__(self, args: list[str], stderr: Path) -> None:
        self.stderr = stderr
        self.err = open(stderr, "wb")
        env = dict(os.environ, ASAN_OPTIONS="detect_leaks=0:abort_on_error=0",
                   UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1")
        self.proc = subprocess.Popen([str(_exe()), *args, "--host", "pty"], stdout=subprocess.PIPE, stderr=self.err,
                                     stdin=subprocess.DEVNULL, env=env)
        assert self.proc.stdout is not None
        line = _readline(self.proc.stdout, "board: listening on ", self.proc, stderr)
        self.port = line.split()[-1]
        self.ser = serial.Serial(self.port, 115200, timeout=0)
        self.dec = FrameDecoder()
        self.seq = 0
        self.got: list[Frame | DecodeError] = []

    def send(self, msg: Message) -> int:
        s = self.seq
        self.seq = (self.seq + 1) & 0xFFFF
        self.ser.write(encode_frame(msg, s))
        return s

    def of(self, cls: type) -> list[Any]:
        return [f.msg for f in self.got if isinstance(f, Frame) and isinstance(f.msg, cls)]

    def wait(self, pred: Callable[[], bool], what: str) -> None:
        end = time.monotonic() + WAIT_S
        while time.monotonic() < end:
            if pred():
                return
            select.select([self.ser.fileno()], [], [], 0.2)
            self.got += self.dec.feed(self.ser.read(65536))
            if self.proc.poll() is not None:
                raise AssertionError(f"the firmware exited ({self.proc.returncode}): {self.stderr.read_text()[-3000:]}")
        raise AssertionError(f"timed out waiting for {what}:\n{self.stderr.read_text()[-3000:]}")

    def until(self, t_us: int) -> None:
        """ADVANCE to board time ``t_us`` and wait for its telemetry."""
        self.send(Advance(t_us))
        self.wait(lambda: any(t.board_time_us >= t_us for t in self.of(Telemetry)), f"telemetry at {t_us} us")

    def hello(self) -> Caps:
        self.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0))
        self.wait(lambda: bool(self.of(Caps)), "CAPS")
        return self.of(Caps)[0]

    def stop(self) -> int:
        """SIGTERM, as the launcher stops it; its exit status."""
        self.ser.close()
        self.proc.send_signal(signal.SIGTERM)
        try:
            rc = self.proc.wait(30)
        finally:
            self.err.close()
        text = self.stderr.read_text()
        assert "AddressSanitizer" not in text and "runtime error" not in text, text[-3000:]
        return rc


def _readline(f: Any, prefix: str, proc: subprocess.Popen[bytes], log: Path | None = None) -> str:
    end = time.monotonic() + WAIT_S
    buf = b""
    while time.monotonic() < end:
        r, _, _ = select.select([f], [], [], 0.5)
        if r:
            chunk = os.read(f.fileno(), 4096)
            buf += chunk
            for line in buf.decode(errors="replace").splitlines():
                if line.startswith(prefix):
                    return line
        if proc.poll() is not None:
            raise AssertionError(f"exited ({proc.returncode}) before {prefix!r}: {buf!r} "
                                 f"{log.read_text()[-2000:] if log else ''}")
    raise AssertionError(f"no {prefix!r} line within {WAIT_S} s: {buf!r}")


@contextmanager
def plant_process(protocol: str, baud: int, *extra: str) -> Iterator[str]:
    """``python -m firmware_sim.plant --protocol P --baud N --lockstep EXTRA`` (its pty's path)."""
    proc = subprocess.Popen([sys.executable, "-m", "firmware_sim.plant", "--protocol", protocol, "--baud", str(baud),
                             "--lockstep", *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT,
                            stdin=subprocess.DEVNULL)
    try:
        assert proc.stdout is not None
        yield _readline(proc.stdout, "plant: servo bus on ", proc).split()[-1]
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@contextmanager
def plant_thread(protocol: str, baud: int, conditions: Conditions | None = None,
                 before: Callable[[World], None] | None = None) -> Iterator[tuple[PlantBus, str]]:
    """The plant's serve loop in a thread of this process: (the plant, its pty's path)."""
    world = World(ROBOT, conditions=conditions)
    if before is not None:
        before(world)
    plant = PlantBus(world, lockstep=True, baud=baud, protocol=protocol)
    port = PtyPort()
    set_line_speed(port.slave, baud)
    stop = threading.Event()
    th = threading.Thread(target=serve, args=(plant, port, stop), daemon=True)
    th.start()
    try:
        yield plant, port.name
    finally:
        stop.set()
        th.join(10)
        port.close()


def _wait_for(pred: Callable[[], bool], what: str) -> None:
    """A condition another thread makes true (the plant's), polled with a failure bound."""
    end = time.monotonic() + WAIT_S
    while not pred():
        if time.monotonic() > end:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.01)


def _record_steps(plant: PlantBus) -> list[tuple[list[int], list[bool]]]:
    """(goal steps, torque) of every servo at each world step (each goal SYNC WRITE, in lockstep)."""
    rec: list[tuple[list[int], list[bool]]] = []
    world = plant.world
    step = world.step

    def recorded() -> None:
        rec.append(([st.goal_steps for st in world.servos], [st.torque for st in world.servos]))
        step()

    world.step = recorded  # type: ignore[method-assign]
    return rec


# -- a real tty, as a USB adapter appears ---------------------------------------------------------------

@pytest.mark.parametrize("protocol,baud", [("sts", 1_000_000), ("dxl2", 57_600), ("dxl2", 1_000_000)])
def test_native_firmware_drives_the_servos_over_a_real_tty(protocol: str, baud: int, tmp_path: Path) -> None:
    with plant_process(protocol, baud) as tty:
        b = NativeBoard(["--bus", f"tty:{tty}:{baud}", "--protocol", protocol, "--lockstep"], tmp_path / "fw.stderr")
        try:
            caps = b.hello()
            assert caps.servo_count == N
            q0 = list(ROBOT.pose(ROBOT.start_pose))
            q1 = list(q0)
            q1[8] = q0[8] + 0.5  # head yaw
            for k in range(1, 51):  # 0.5 s: the head turns 0.5 rad
                q = [a + (c - a) * k / 50 for a, c in zip(q0, q1)]
                b.send(ServoFrame(10_000 * k, MASK, q))
            b.until(1_000_000)
            last = b.of(Telemetry)[-1]
            assert abs(last.positions[8] - q1[8]) < 0.05, last.positions
            assert not last.faults & FaultFlags.SERVO_FAULT
        finally:
            assert b.stop() == 0
    err = (tmp_path / "fw.stderr").read_text()
    assert f"board: servo bus ({protocol}, {baud} baud): {N} servos" in err, err
    assert "(model 1200)" in err if protocol == "dxl2" else "(model 777)" in err
    assert "board: stopping: torque off for every servo on the bus" in err


def test_a_missing_device_is_one_line_and_status_2(tmp_path: Path) -> None:
    r = subprocess.run([str(_exe()), "--bus", "tty:/dev/ttyGS-missing:1000000", "--protocol", "dxl2"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "/dev/ttyGS-missing" in lines[0] and "No such file" in lines[0], r.stderr


def test_a_baud_the_device_refuses_is_one_line_and_status_2(tmp_path: Path) -> None:
    port = PtyPort()
    try:
        for spec, why in ((f"tty:{port.name}:1234567", "1234567 baud"), ("tty:/dev/null:57600", "not a tty")):
            r = subprocess.run([str(_exe()), "--bus", spec], capture_output=True, text=True, timeout=60)
            assert r.returncode == 2, r.stderr
            lines = r.stderr.strip().splitlines()
            assert len(lines) == 1 and why in lines[0] and spec.split(":")[1] in lines[0], r.stderr
    finally:
        port.close()


# -- hardware safety ------------------------------------------------------------------------------------

@pytest.mark.parametrize("protocol", ["sts", "dxl2"])
def test_start_up_from_a_non_neutral_pose_ramps_and_stop_turns_torque_off(protocol: str, tmp_path: Path) -> None:
    """The head starts 0.6 rad off neutral: the first goal written is where it is (no jump), torque goes on with
    it, the command then ramps to the first frames at the servo's speed, and a stop leaves every servo limp."""
    def turn_head(world: World) -> None:
        world.data.qpos[world.cm.qpos_adr[8]] = 0.6
        world.refresh()

    with plant_thread(protocol, 1_000_000, before=turn_head) as (plant, tty):
        rec = _record_steps(plant)
        start = plant.world.servos[8].present_steps
        assert abs(start - _steps(8, 0.6)) <= 1
        b = NativeBoard(["--bus", f"tty:{tty}:1000000", "--protocol", protocol, "--lockstep"], tmp_path / "fw.stderr")
        try:
            b.hello()
            q = list(ROBOT.pose(ROBOT.start_pose))
            for k in range(1, 101):  # 1 s of frames at the start pose: head yaw 0
                b.send(ServoFrame(10_000 * k, MASK, q))
            b.until(1_000_000)
            tel = b.of(Telemetry)
            assert abs(tel[0].positions[8] - 0.6) < 0.08, tel[0].positions[8]  # 20 ms into the ramp
            assert abs(tel[-1].positions[8] - q[8]) < 0.05, tel[-1].positions[8]
            goals, torque = rec[0]
            assert abs(goals[8] - start) <= 1, (goals[8], start)  # the first goal: where the head was
            assert all(rec[1][1]), rec[1][1]  # torque on from the first goal write's tick on
            # the ramp: no goal moves more than the servo's speed allows per tick (and it does move)
            per_tick = ROBOT.servos[8].max_speed * 0.002 / ROBOT.servos.model.resolution + 2
            heads = [g[8] for g, _ in rec]
            assert max(abs(a - c) for a, c in zip(heads, heads[1:])) <= per_tick
            assert abs(heads[-1] - _steps(8, q[8])) <= 2
            for g, _ in rec:  # every goal inside its servo's step range
                for i in range(N):
                    lo, hi = _step_range(i)
                    assert lo <= g[i] <= hi, (i, g[i], lo, hi)
            assert all(st.torque for st in plant.world.servos)
        finally:
            assert b.stop() == 0
        _wait_for(lambda: not any(st.torque for st in plant.world.servos), "torque off on every servo")
    assert "board: stopping: torque off" in (tmp_path / "fw.stderr").read_text()


def test_goals_outside_the_servo_table_are_held_to_its_step_range(tmp_path: Path) -> None:
    with plant_thread("dxl2", 1_000_000) as (plant, tty):
        rec = _record_steps(plant)
        b = NativeBoard(["--bus", f"tty:{tty}:1000000", "--protocol", "dxl2", "--lockstep"], tmp_path / "fw.stderr")
        try:
            b.hello()
            far = [s.max + 3.0 for s in ROBOT.servos]
            for k in range(1, 201):  # 1 s beyond every maximum, then 1 s beyond every minimum
                b.send(ServoFrame(10_000 * k, MASK, far if k <= 100 else [-x for x in far]))
            b.until(2_000_000)
        finally:
            assert b.stop() == 0
    assert len(rec) >= 900
    hit = [[False, False] for _ in range(N)]
    for g, _ in rec:
        for i in range(N):
            lo, hi = _step_range(i)
            assert lo <= g[i] <= hi, (i, g[i], lo, hi)
            hit[i][0] |= g[i] <= lo + 1
            hit[i][1] |= g[i] >= hi - 1
    assert all(a and c for a, c in hit), hit  # each servo was driven to both ends of its range


@pytest.mark.parametrize("torque", ["hold", "limp"])
def test_estop_holds_or_goes_limp(torque: str, tmp_path: Path) -> None:
    with plant_thread("sts", 1_000_000) as (plant, tty):
        b = NativeBoard(["--bus", f"tty:{tty}:1000000", "--lockstep", "--estop-torque", torque], tmp_path / "fw.stderr")
        try:
            b.hello()
            q = list(ROBOT.pose(ROBOT.start_pose))
            for k in range(1, 31):
                b.send(ServoFrame(10_000 * k, MASK, q))
            b.until(300_000)
            assert all(st.torque for st in plant.world.servos)
            b.send(Estop())
            b.until(400_000)
            assert all(st.torque == (torque == "hold") for st in plant.world.servos)
            b.send(EstopClear())
            b.until(500_000)
            assert all(st.torque for st in plant.world.servos)
            assert not b.of(Telemetry)[-1].faults & FaultFlags.ESTOP
        finally:
            assert b.stop() == 0


# -- servo error bits -> one line with id and name, SERVO_FAULT, torque off for that servo ----------------

def _drive_into_error(b: NativeBoard) -> None:
    b.hello()
    q = list(ROBOT.pose(ROBOT.start_pose))
    for k in range(1, 41):
        b.send(ServoFrame(10_000 * k, MASK, q))
    b.until(1_000_000)


def _check_error_reported(b: NativeBoard, err: str, sid: int, what: str) -> None:
    name = ROBOT.servos[sid - 1].name
    nacks = [n for n in b.of(Nack) if n.reason == NackReason.SERVO_FAULT]
    # one unsolicited NACK names the servo and its error; the frames after it are refused naming it too
    assert nacks and nacks[0].detail == f"servo id {sid} ({name}) {what}; torque off", nacks
    assert all(n.detail == f"servo id {sid} ({name}) {what}; send ESTOP_CLEAR" for n in nacks[1:]), nacks
    tel = b.of(Telemetry)
    faulted = [t for t in tel if t.faults & FaultFlags.SERVO_FAULT]
    assert faulted and 300_000 <= faulted[0].board_time_us <= 400_000, [t.board_time_us for t in faulted[:3]]
    lines = [ln for ln in err.splitlines() if ln.startswith(f"board: servo {sid} ")]
    assert len(lines) == 1 and lines[0].startswith(f"board: servo {sid} ({name}): {what}"), err
    # the host turns the NACK into its one line, naming the servo, its error and the way out
    from types import SimpleNamespace

    from host.link.faultcheck import servo_fault_message

    line = servo_fault_message(SimpleNamespace(servo_fault=nacks[0], link_spec="pty"), faulted[0].board_time_us)  # type: ignore[arg-type]
    assert f"servo id {sid} ({name}) {what}" in line and "--clear" in line and "\n" not in line, line


@pytest.mark.parametrize("protocol", ["sts", "dxl2"])
def test_servo_error_bits_raise_servo_fault_and_torque_off(protocol: str, tmp_path: Path) -> None:
    cond = Conditions(errors=(ServoError(3, Fault.OVERHEAT, 300_000),))
    with plant_thread(protocol, 1_000_000, conditions=cond) as (plant, tty):
        b = NativeBoard(["--bus", f"tty:{tty}:1000000", "--protocol", protocol, "--lockstep"], tmp_path / "fw.stderr")
        try:
            _drive_into_error(b)
            _check_error_reported(b, (tmp_path / "fw.stderr").read_text(), 3, "overheating")
            torque = [st.torque for st in plant.world.servos]
            assert torque == [i != 2 for i in range(N)], torque
            # frames are refused with the error named; ESTOP_CLEAR tries again and the error latches anew
            seq = b.send(ServoFrame(1_010_000, MASK, list(ROBOT.pose(ROBOT.start_pose))))
            b.wait(lambda: any(n.ack_seq == seq for n in b.of(Nack)), "the refusal")
            refusal = next(n for n in b.of(Nack) if n.ack_seq == seq)
            assert refusal.reason == NackReason.SERVO_FAULT and "overheating; send ESTOP_CLEAR" in refusal.detail
            b.send(EstopClear())
            b.until(1_200_000)
            assert b.of(Telemetry)[-1].faults & FaultFlags.SERVO_FAULT
        finally:
            assert b.stop() == 0


def test_plant_error_flag_over_a_real_tty(tmp_path: Path) -> None:
    """The plant's own ``--error ID=overload@SECONDS`` (Dynamixel: alert bit, then register 70)."""
    with plant_process("dxl2", 1_000_000, "--error", "3=overload@0.3") as tty:
        b = NativeBoard(["--bus", f"tty:{tty}:1000000", "--protocol", "dxl2", "--lockstep"], tmp_path / "fw.stderr")
        try:
            _drive_into_error(b)
            _check_error_reported(b, (tmp_path / "fw.stderr").read_text(), 3, "overload")
        finally:
            assert b.stop() == 0


# -- calibration.toml (a real bus's build) ----------------------------------------------------------------

def test_a_real_bus_build_carries_the_calibration(tmp_path: Path) -> None:
    """The servo table of a real-bus build (``build(..., calibrated=True)``, what the launcher uses with
    ``servo_bus_port``) has the robot's calibration: against servos mounted off centre and reversed as the
    file says, the joints go where the frames say and telemetry reads them back."""
    import shutil

    from robots.hardware import Calibration, ServoCalibration, save_calibration
    from robots.loader import load_robot_dir

    root = tmp_path / "coco"
    shutil.copytree(ROBOT.root, root)
    head_yaw, head_pitch = ROBOT.servos[8], ROBOT.servos[9]
    save_calibration(root, Calibration({head_yaw.name: ServoCalibration(9, offset_steps=300),
                                        head_pitch.name: ServoCalibration(10, direction=-1)}), list(ROBOT.servos))
    robot = load_robot_dir(root)
    exe = build("native-asan", robot, calibrated=True)
    assert exe != build("native-asan", robot)
    world = World(robot, conditions=Conditions(offsets={9: 300}, reversed=frozenset({10})))
    plant = PlantBus(world, lockstep=True, protocol="dxl2")
    port = PtyPort()
    set_line_speed(port.slave, 1_000_000)
    stop = threading.Event()
    th = threading.Thread(target=serve, args=(plant, port, stop), daemon=True)
    th.start()
    err = tmp_path / "fw.stderr"
    proc = subprocess.Popen([str(exe), "--bus", f"tty:{port.name}:1000000", "--protocol", "dxl2", "--lockstep",
                             "--host", "pty"], stdout=subprocess.PIPE, stderr=open(err, "wb"), stdin=subprocess.DEVNULL)
    try:
        assert proc.stdout is not None
        ser = serial.Serial(_readline(proc.stdout, "board: listening on ", proc, err).split()[-1], 115200, timeout=0)
        dec, got = FrameDecoder(), []
        q = list(ROBOT.pose(ROBOT.start_pose))
        q[8], q[9] = 0.4, 0.3
        frames = [Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0)] + [ServoFrame(10_000 * k, MASK, q) for k in range(1, 101)]
        for seq, m in enumerate([*frames, Advance(1_000_000)]):
            ser.write(encode_frame(m, seq))
        end = time.monotonic() + WAIT_S
        while not any(isinstance(f, Frame) and isinstance(f.msg, Telemetry) and f.msg.board_time_us >= 1_000_000
                      for f in got):
            assert time.monotonic() < end and proc.poll() is None, err.read_text()[-2000:]
            select.select([ser.fileno()], [], [], 0.2)
            got += dec.feed(ser.read(65536))
        last = [f.msg for f in got if isinstance(f, Frame) and isinstance(f.msg, Telemetry)][-1]
        actual = world.positions()
        assert abs(actual[8] - 0.4) < 0.03 and abs(actual[9] - 0.3) < 0.03, actual[8:10]
        assert abs(last.positions[8] - 0.4) < 0.03 and abs(last.positions[9] - 0.3) < 0.03, last.positions[8:10]
        ser.close()
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(30)
        stop.set()
        th.join(10)
        port.close()


# -- the launcher with a real bus ---------------------------------------------------------------------------

_LAUNCH = """
import sys
from firmware_sim.cfirmware.launcher import LaunchOptions, run_firmware
from robots.registry import load_robot
sys.exit(run_firmware(LaunchOptions(robot=load_robot("coco"), lockstep=True, servo_bus_port=sys.argv[1],
                                    servo_bus_baud=int(sys.argv[2]), bus_protocol=sys.argv[3])))
"""


def test_the_launcher_hands_a_real_bus_to_the_firmware_and_runs_no_plant(tmp_path: Path) -> None:
    err = tmp_path / "board.stderr"
    with plant_process("dxl2", 57_600) as tty:
        proc = subprocess.Popen([sys.executable, "-c", _LAUNCH, tty, "57600", "dxl2"], stdout=subprocess.PIPE,
                                stderr=open(err, "wb"), stdin=subprocess.DEVNULL, cwd=ROOT)
        try:
            assert proc.stdout is not None
            ser = serial.Serial(_readline(proc.stdout, "board: listening on ", proc, err).split()[-1], 115200, timeout=0)
            ser.write(encode_frame(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), 0))
            dec, got = FrameDecoder(), []
            end = time.monotonic() + WAIT_S
            while not any(isinstance(f, Frame) and isinstance(f.msg, Caps) for f in got):
                assert time.monotonic() < end and proc.poll() is None, err.read_text()[-2000:]
                select.select([ser.fileno()], [], [], 0.2)
                got += dec.feed(ser.read(65536))
            ser.close()
        finally:
            proc.send_signal(signal.SIGTERM)
            rc = proc.wait(60)
    text = err.read_text()
    assert rc == 130, text[-2000:]
    assert "board: servo bus (dxl2, 57600 baud): 12 servos (model 1200)" in text, text
    assert "board: stopping: torque off for every servo on the bus" in text
    assert "ticks, bus time per tick" not in text  # no plant of the launcher's (its statistics line)


def test_a_real_bus_needs_the_native_firmware() -> None:
    import io

    from firmware_sim.cfirmware.launcher import LaunchOptions, run_firmware

    err = io.StringIO()
    assert run_firmware(LaunchOptions(robot=ROBOT, firmware="qemu", servo_bus_port="/dev/ttyUSB0"), err) == 2
    lines = err.getvalue().strip().splitlines()
    assert len(lines) == 1 and "--firmware c" in lines[0] and "QEMU" in lines[0], lines


_LAUNCH_PLANT = """
import sys
from firmware_sim.cfirmware.launcher import LaunchOptions, run_firmware
from robots.registry import load_robot
sys.exit(run_firmware(LaunchOptions(robot=load_robot("coco"), lockstep=False, bus_protocol=sys.argv[1])))
"""


def test_realtime_over_the_launchers_plant_in_dxl2_mode(tmp_path: Path) -> None:
    """Realtime (wall-clock ticks, the plant's physics on the wall clock too): the Dynamixel bus keeps up at
    500 Hz and no servo is taken for lost."""
    err = tmp_path / "board.stderr"
    proc = subprocess.Popen([sys.executable, "-c", _LAUNCH_PLANT, "dxl2"], stdout=subprocess.PIPE,
                            stderr=open(err, "wb"), stdin=subprocess.DEVNULL, cwd=ROOT)
    try:
        assert proc.stdout is not None
        ser = serial.Serial(_readline(proc.stdout, "board: listening on ", proc, err).split()[-1], 115200, timeout=0)
        dec, got = FrameDecoder(), []

        def tel() -> list[Telemetry]:
            return [f.msg for f in got if isinstance(f, Frame) and isinstance(f.msg, Telemetry)]

        ser.write(encode_frame(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), 0))
        end = time.monotonic() + WAIT_S
        while not tel() or tel()[-1].board_time_us < 1_500_000:
            assert time.monotonic() < end and proc.poll() is None, err.read_text()[-2000:]
            select.select([ser.fileno()], [], [], 0.1)
            got += dec.feed(ser.read(65536))
        assert not any(t.faults & FaultFlags.SERVO_FAULT for t in tel())
        assert any(abs(p) > 0 for p in tel()[-1].positions)
        ser.close()
    finally:
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(60)
    text = err.read_text()
    assert rc == 130, text[-2000:]
    assert "board: servo bus (dxl2): 12 servos (model 1200)" in text and "stopped answering" not in text, text
