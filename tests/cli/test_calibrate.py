"""``ghostshell robots calibrate``: the hand-guided calibration against the emulated servo bus (the plant,
in a thread of this process on a real pty, driven through the vendor SDKs as real servos would be).

A "hand" moves the joints: the injected input function sets the plant world's joint positions (MuJoCo
qpos, then ``world.refresh()``) before it answers Enter. The plant is told to mount servos with another
zero (offset) or the other way round (reversed); the written calibration.toml must recover exactly what
was injected, and round-trip through :func:`robots.hardware.load_calibration`.
"""

from __future__ import annotations

import argparse
import builtins
import math
import shutil
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from typing import Any
from dataclasses import dataclass
from pathlib import Path

import dynamixel_sdk.port_handler
import pytest
import scservo_sdk.port_handler

import host.cli
from firmware_sim.plant.bus import PlantBus
from firmware_sim.plant.conditions import Conditions
from firmware_sim.plant.server import serve, set_line_speed
from firmware_sim.plant.world import World
from firmware_sim.transports.ports import PtyPort
from host.commands.calibrate import run
from robots.datatypes import Servo
from robots.hardware import CALIBRATION_FILE, Calibration, ServoCalibration, load_calibration
from robots.hardware import rad_to_steps, steps_to_rad
from robots.loader import load_robot_dir
from robots.registry import BUILTIN_DIR

ROBOT = "arm"


# --- the plant with injected mounting -----------------------------------------------------------------


@dataclass
class Plant:
    world: World
    bus: PlantBus
    port: PtyPort
    conditions: Conditions

    @property
    def step(self) -> float:
        return self.world.step_rad

    def raw(self, s: Servo, q: float) -> int:
        """The present position the plant reports for joint angle ``q`` (its injected mounting)."""
        c = self.conditions
        cal = ServoCalibration(s.id, c.offsets.get(s.id, 0), -1 if s.id in c.reversed else 1)
        return rad_to_steps(s, cal, q, self.step)

    def torque(self, s: Servo) -> bool:
        return self.world.servos[s.index].torque


@pytest.fixture
def robots_dir(tmp_path: Path) -> Path:
    """A user robot folder holding a copy of the built-in arm (a user's SO-101-like arm)."""
    d = tmp_path / "robots"
    shutil.copytree(BUILTIN_DIR / ROBOT, d / ROBOT, ignore=shutil.ignore_patterns("__pycache__"))
    return d


@pytest.fixture
def start_plant(robots_dir: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[..., Plant]]:
    # The plant answers from a thread of this process; the SDK polls its port in a busy loop holding the
    # GIL: give the plant's thread its turns sooner and the SDK a USB adapter's latency-timer allowance
    # (tests/cfirmware/test_vendor_sdk.py).
    old = sys.getswitchinterval()
    sys.setswitchinterval(0.0002)
    monkeypatch.setattr(scservo_sdk.port_handler, "LATENCY_TIMER", 100)
    monkeypatch.setattr(dynamixel_sdk.port_handler, "LATENCY_TIMER", 100)
    running: list[tuple[threading.Event, threading.Thread, PtyPort]] = []

    def start(protocol: str = "sts", baud: int = 1_000_000, **conditions: Any) -> Plant:
        robot = load_robot_dir(robots_dir / ROBOT)
        c = Conditions(**conditions)
        world = World(robot, conditions=c)
        bus = PlantBus(world, lockstep=True, protocol=protocol, baud=baud)  # lockstep: no goal writes, physics never steps
        for st in world.servos:  # whatever the servos start with, the command must leave them limp
            st.torque = True
        port = PtyPort()
        set_line_speed(port.slave, bus.baud)
        stop = threading.Event()
        th = threading.Thread(target=serve, args=(bus, port, stop), daemon=True)
        th.start()
        running.append((stop, th, port))
        return Plant(world, bus, port, c)

    yield start
    for stop, th, port in running:
        stop.set()
        th.join(5)
        port.close()
    sys.setswitchinterval(old)


# --- the hand ------------------------------------------------------------------------------------------


class Hand:
    """The injected input: per prompt, moves the plant's joints as a person would, then answers Enter.

    Prompts arrive in order: the reference pose, one per joint (direction), the range. ``reference``,
    ``nudge`` (joint index -> angle to move it to for its direction prompt) and ``sweep`` (joint index ->
    the angles visited while the range is recorded) default to a careful user."""

    def __init__(self, plant: Plant, robot, *, reference: dict[int, float] | None = None,
                 nudge: dict[int, float | None] | None = None, sweep: dict[int, Sequence[float]] | None = None,
                 interrupt_at: str | None = None) -> None:
        self.plant, self.robot = plant, robot
        self.servos = list(robot.servos)
        self.reference = {i: s.neutral for i, s in enumerate(self.servos)} | (reference or {})
        self.nudge = {i: s.neutral + math.radians(12) for i, s in enumerate(self.servos)} | (nudge or {})
        self.sweep = {i: (s.min, s.max, s.neutral) for i, s in enumerate(self.servos)} | (sweep or {})
        self.interrupt_at = interrupt_at
        self.prompts: list[str] = []
        self.said: list[str] = []
        self._sweeps = 0
        self._cv = threading.Condition()

    def set(self, i: int, q: float) -> None:
        w = self.plant.world
        w.data.qpos[w.cm.qpos_adr[i]] = q
        w.refresh()

    def live(self, pos: Sequence[int], mins: Sequence[int], maxes: Sequence[int]) -> None:
        with self._cv:
            self._sweeps += 1
            self._cv.notify_all()

    def _wait_sweeps(self, n: int = 2) -> None:
        """Until the command has read every position ``n`` more times (it polls while we move)."""
        with self._cv:
            target = self._sweeps + n
            assert self._cv.wait_for(lambda: self._sweeps >= target, timeout=20), "the command stopped reading"

    def say(self, line: str) -> None:
        self.said.append(line)

    def ask(self, prompt: str) -> str:
        self.prompts.append(prompt)
        k = len(self.prompts) - 1
        n = len(self.servos)
        phase = "reference" if k == 0 else "direction" if k <= n else "range"
        if self.interrupt_at == phase:
            raise KeyboardInterrupt
        if phase == "reference":
            for i, q in self.reference.items():
                self.set(i, q)
        elif phase == "direction":
            q = self.nudge[k - 1]
            if q is not None:
                self.set(k - 1, q)
        else:
            self._wait_sweeps()
            w = self.plant.world
            for i, angles in self.sweep.items():
                for q in angles:  # by hand: at most 40 deg between two readings (no jump the encoder could wrap)
                    q0 = float(w.data.qpos[w.cm.qpos_adr[i]])
                    n = max(1, math.ceil(abs(q - q0) / math.radians(40)))
                    for k in range(1, n + 1):
                        self.set(i, q0 + (q - q0) * k / n)
                        self._wait_sweeps()
        return ""


def _args(robots_dir: Path, port: str, *extra: str) -> argparse.Namespace:
    ns = host.cli.build_parser(["robots"]).parse_args(
        ["robots", "calibrate", ROBOT, "--servo-bus", port, "--robots-dir", str(robots_dir), *extra])
    return ns


def _calibrate(robots_dir: Path, plant: Plant, hand: Hand, *extra: str) -> int:
    return run(_args(robots_dir, plant.port.name, *extra), ask=hand.ask, say=hand.say, live=hand.live)


# --- recovery --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("protocol", ["sts", "dxl2"])
@pytest.mark.parametrize("offsets, reverse", [
    ({}, set()),
    ({1: 37, 2: -250, 3: 400, 5: -1, 6: 91}, {2, 4, 6}),
], ids=["as-built", "offsets-and-reversed"])
def test_calibration_recovers_the_mounting_and_round_trips(robots_dir, start_plant, protocol, offsets, reverse) -> None:
    plant = start_plant(protocol, offsets=offsets, reversed=frozenset(reverse))
    extra = ("--bus-protocol", protocol) if protocol != "sts" else ()
    robot = load_robot_dir(robots_dir / ROBOT)
    hand = Hand(plant, robot)
    assert _calibrate(robots_dir, plant, hand, *extra) == 0, hand.said
    servos = list(robot.servos)
    assert len(hand.prompts) == len(servos) + 2
    assert any("neutral" in line and "'zero'" in line for line in hand.said), hand.said  # the pose named

    written = load_calibration(robots_dir / ROBOT, servos)
    expected = {s.name: ServoCalibration(s.id, offsets.get(s.id, 0), -1 if s.id in reverse else 1,
                                         min(plant.raw(s, s.min), plant.raw(s, s.max)),
                                         max(plant.raw(s, s.min), plant.raw(s, s.max))) for s in servos}
    assert dict(written.servos) == expected
    # what the board will compute from it: every joint angle back from the raw position, to one step
    for s in servos:
        for q in (s.min, s.neutral, s.max, 0.3 * s.min + 0.7 * s.max):
            assert abs(steps_to_rad(s, written.of(s), plant.raw(s, q), plant.step) - q) <= plant.step / 2 + 1e-9
    assert not any(plant.torque(s) for s in servos), "torque left on"


# --- bad input: one line naming servo id and name, exit 2, nothing written ---------------------------


def _refused(robots_dir: Path, plant: Plant, hand: Hand, capsys: pytest.CaptureFixture[str], *extra: str) -> str:
    status = _calibrate(robots_dir, plant, hand, *extra)
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert status == 2 and len(err) == 1, (status, err)
    assert not (robots_dir / ROBOT / CALIBRATION_FILE).exists()
    assert not any(plant.torque(s) for s in hand.servos) or not hand.prompts
    return err[0]


def test_a_missing_servo_is_named(robots_dir, start_plant, capsys) -> None:
    plant = start_plant(missing=frozenset({3}))
    hand = Hand(plant, load_robot_dir(robots_dir / ROBOT))
    line = _refused(robots_dir, plant, hand, capsys)
    assert line.startswith("ghostshell robots: servo 3 (elbow_flex) does not answer a ping"), line
    assert hand.prompts == []


@pytest.mark.parametrize("protocol, model", [("sts", 777), ("dxl2", 1200)])
def test_a_servo_of_another_model_is_named(robots_dir, start_plant, capsys, protocol, model) -> None:
    plant = start_plant(protocol, models={2: 1020})  # an XM430 where hardware.toml says otherwise
    hand = Hand(plant, load_robot_dir(robots_dir / ROBOT))
    line = _refused(robots_dir, plant, hand, capsys, "--bus-protocol", protocol)
    assert line == (f"ghostshell robots: servo 2 (shoulder_lift) reports model number 1020, hardware.toml says {model}: "
                    "a different servo, or fix hardware.toml (model / [models])"), line


def test_a_wrong_model_in_hardware_toml_is_named(robots_dir, start_plant, capsys) -> None:
    (robots_dir / ROBOT / "hardware.toml").write_text('protocol = "sts"\n[models]\ngripper = 1200\n')
    plant = start_plant()
    hand = Hand(plant, load_robot_dir(robots_dir / ROBOT))
    line = _refused(robots_dir, plant, hand, capsys)
    assert "servo 6 (gripper) reports model number 777, hardware.toml says 1200" in line, line


def test_a_direction_move_too_small_to_tell(robots_dir, start_plant, capsys) -> None:
    plant = start_plant()
    robot = load_robot_dir(robots_dir / ROBOT)
    hand = Hand(plant, robot, nudge={3: robot.servos[3].neutral + math.radians(2)})
    line = _refused(robots_dir, plant, hand, capsys)
    assert "servo 4 (wrist_flex)" in line and "too little to tell its direction" in line, line


def test_a_joint_not_moved_through_its_range(robots_dir, start_plant, capsys) -> None:
    plant = start_plant()
    robot = load_robot_dir(robots_dir / ROBOT)
    s = robot.servos[1]
    hand = Hand(plant, robot, nudge={1: s.neutral}, sweep={1: ()})  # direction: not moved -> refused first
    line = _refused(robots_dir, plant, hand, capsys)
    assert "servo 2 (shoulder_lift)" in line, line
    # moved for its direction, then left there: min == max
    plant2 = start_plant()
    hand = Hand(plant2, robot, sweep={1: ()})
    line = _refused(robots_dir, plant2, hand, capsys)
    assert "servo 2 (shoulder_lift): its range" in line and "is empty (min >= max)" in line, line


def test_a_range_without_the_reference_pose(robots_dir, start_plant, capsys) -> None:
    plant = start_plant()
    robot = load_robot_dir(robots_dir / ROBOT)
    s = robot.servos[2]
    hand = Hand(plant, robot, nudge={2: s.neutral + math.radians(40)}, sweep={2: (s.max, s.neutral + math.radians(40))})
    line = _refused(robots_dir, plant, hand, capsys)
    assert "servo 3 (elbow_flex): its range" in line and "does not contain the reference pose" in line, line


def test_a_range_outside_the_joints_range(robots_dir, start_plant, capsys) -> None:
    """Seen when the reference pose was held wrong (e.g. a joint half a range off): every position
    recorded lies beyond the joint's range as the offset places it (robots.hardware.step_limits)."""
    plant = start_plant()
    robot = load_robot_dir(robots_dir / ROBOT)
    s = robot.servos[0]
    far = s.max + math.radians(20)
    hand = Hand(plant, robot, nudge={0: far}, sweep={0: (far + math.radians(30), far)})
    line = _refused(robots_dir, plant, hand, capsys)
    assert "servo 1 (shoulder_pan): its range" in line and "lies outside its joint range -110..+110 deg" in line, line


# --- Ctrl-C: torque off, nothing written, exit 130 (through the CLI) --------------------------------------


@pytest.mark.parametrize("phase", ["reference", "direction", "range"])
def test_ctrl_c_leaves_torque_off_and_writes_nothing(robots_dir, start_plant, monkeypatch, capsys, phase) -> None:
    plant = start_plant()
    robot = load_robot_dir(robots_dir / ROBOT)
    hand = Hand(plant, robot, interrupt_at=phase)
    monkeypatch.setattr(builtins, "input", hand.ask)
    status = host.cli.main(["robots", "calibrate", ROBOT, "--servo-bus", plant.port.name, "--robots-dir", str(robots_dir)])
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert status == 130 and err == ["ghostshell robots: interrupted by SIGINT (Ctrl-C)"], (status, err)
    assert not (robots_dir / ROBOT / CALIBRATION_FILE).exists()
    assert not any(plant.torque(s) for s in robot.servos)


def test_end_of_input_writes_nothing(robots_dir, start_plant, capsys) -> None:
    plant = start_plant()
    hand = Hand(plant, load_robot_dir(robots_dir / ROBOT))

    def eof(prompt: str) -> str:
        raise EOFError

    status = run(_args(robots_dir, plant.port.name), ask=eof, say=hand.say)
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert status == 1 and len(err) == 1 and "input ended" in err[0], err
    assert not (robots_dir / ROBOT / CALIBRATION_FILE).exists()


def test_a_recalibration_replaces_the_file(robots_dir, start_plant) -> None:
    plant = start_plant(offsets={4: 12}, reversed=frozenset({5}))
    robot = load_robot_dir(robots_dir / ROBOT)
    (robots_dir / ROBOT / CALIBRATION_FILE).write_text("[servo.wrist_roll]\nid = 5\noffset_steps = 999\n")
    hand = Hand(plant, robot)
    assert _calibrate(robots_dir, plant, hand) == 0
    assert any("replaces" in line for line in hand.said)
    cal = load_calibration(robots_dir / ROBOT, list(robot.servos))
    assert cal.of(robot.servos[3]).offset_steps == 12 and cal.of(robot.servos[4]).direction == -1
    assert isinstance(cal, Calibration) and len(cal.servos) == len(robot.servos)


def test_a_servo_lost_during_the_procedure_is_exit_1(robots_dir, start_plant, capsys) -> None:
    plant = start_plant()
    robot = load_robot_dir(robots_dir / ROBOT)
    hand = Hand(plant, robot)
    ask = hand.ask

    def unplug_then_ask(prompt: str) -> str:
        if len(hand.prompts) == 2:  # during the direction step of servo 2: its cable comes off
            plant.bus.kill(2, 0)
        return ask(prompt)

    status = run(_args(robots_dir, plant.port.name), ask=unplug_then_ask, say=hand.say, live=hand.live)
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert status == 1 and len(err) == 1, (status, err)
    assert err[0].startswith("ghostshell robots: servo 2 (shoulder_lift) did not answer a present-position read") and \
        err[0].endswith("nothing written"), err
    assert not (robots_dir / ROBOT / CALIBRATION_FILE).exists()


class _FakeBus:
    """Servos that report what ``pos`` says (a real encoder wraps from 4095 to 0; the plant's does not)."""

    def __init__(self, robot) -> None:
        self.pos = {s.id: 2048 for s in robot.servos}
        self.reads = 0

    def ping(self, servo_id: int) -> int:
        return 777

    def torque_off(self, servo_id: int) -> bool:
        return True

    def position(self, servo_id: int) -> int:
        self.reads += 1
        return self.pos[servo_id]


def test_a_range_across_the_encoder_wrap_is_refused(robots_dir) -> None:
    from host.calibration.procedure import CalibrationError, calibrate
    from robots.hardware import Hardware

    robot = load_robot_dir(robots_dir / ROBOT)
    bus = _FakeBus(robot)
    bus.pos[1] = 3900  # shoulder_pan's horn mounted near the encoder's end
    asked: list[str] = []

    def settle() -> None:
        n, waited = bus.reads + 3 * len(bus.pos), 0
        while bus.reads < n and waited < 250:  # the range reader polls meanwhile (until it stops, at the wrap)
            threading.Event().wait(0.002)
            waited += 1

    def ask(prompt: str) -> str:
        asked.append(prompt)
        if len(asked) == 1:
            return ""
        if len(asked) <= 1 + len(bus.pos):
            bus.pos[len(asked) - 1] += 100  # direction: each joint +100 steps
            return ""
        for p in (4095, 20, 150):  # through the end of the encoder and over its wrap
            bus.pos[1] = p
            settle()
        return ""

    with pytest.raises(CalibrationError, match=r"^servo 1 \(shoulder_pan\): its position jumped 4095 -> 20, across the "
                                               r"encoder's 0/4095 wrap"):
        calibrate(robot, bus, Hardware(), ask=ask, say=lambda line: None, poll_s=0.001)


def test_protocol_and_baud_come_from_hardware_toml(robots_dir, start_plant, capsys) -> None:
    (robots_dir / ROBOT / "hardware.toml").write_text('protocol = "dxl2"\nbaud = 57600\n')
    plant = start_plant("dxl2", baud=57600, offsets={6: -33}, reversed=frozenset({1}))
    robot = load_robot_dir(robots_dir / ROBOT)
    hand = Hand(plant, robot)
    assert _calibrate(robots_dir, plant, hand) == 0, hand.said
    assert hand.said[0].endswith("at 57600 baud, dxl2"), hand.said[0]
    cal = load_calibration(robots_dir / ROBOT, list(robot.servos))
    assert cal.of(robot.servos[5]).offset_steps == -33 and cal.of(robot.servos[0]).direction == -1
    # the same servos asked at another baud do not answer (PORT:BAUD overrides hardware.toml)
    (robots_dir / ROBOT / CALIBRATION_FILE).unlink()
    line = _refused(robots_dir, plant, Hand(plant, robot), capsys, "--servo-bus", f"{plant.port.name}:1000000")
    assert line.startswith("ghostshell robots: servo 1 (shoulder_pan) does not answer a ping"), line
