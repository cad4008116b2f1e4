"""The plant's ``--hand``: lines on its stdin hold limp joints at an angle, as a person's hand would.

Unit: the commands on a world (hold, clamp to the range, pose, release, bad lines), a held limp joint that
does not sag while a released one does. End to end (docs/guides/calibration.md's two-terminal walk-through,
as two processes): ``python -m firmware_sim.plant --robot arm --offset 2=120 --reverse 3 --hand`` and
``ghostshell robots calibrate arm --servo-bus PTY``, the hand's lines typed into the plant, Enter into the
command; the calibration.toml written recovers the injected offset and reversal exactly. The test's plant
is ``--lockstep`` (no physics steps without goal writes, so nothing depends on this machine's load: a
realtime plant on a loaded machine answers the SDK late); the guide's realtime walk-through differs only in
that unheld limp joints sag meanwhile, which the unit test above covers."""

from __future__ import annotations

import io
import math
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from firmware_sim.plant.conditions import Conditions
from firmware_sim.plant.hand import Hand
from firmware_sim.plant.world import World
from robots.hardware import CALIBRATION_FILE, STEP_CENTRE, ServoCalibration, load_calibration, rad_to_steps
from robots.registry import BUILTIN_DIR, load_robot

ROOT = Path(__file__).resolve().parents[2]
ARM = load_robot("arm")


def _limp_world() -> tuple[World, Hand, io.StringIO, io.StringIO]:
    world = World(ARM, conditions=Conditions(offsets={2: 120}, reversed=frozenset({3})))
    for st in world.servos:
        st.torque = False
    out, err = io.StringIO(), io.StringIO()
    return world, Hand(world, out, err), out, err


def test_a_held_limp_joint_does_not_sag_and_a_released_one_does() -> None:
    world, hand, out, err = _limp_world()
    lift = ARM.servos[1]  # shoulder_lift: gravity pulls it
    hand.put("shoulder_lift 30")
    hand.put("pose zero")
    hand.put("release shoulder_lift")
    hand.put("shoulder_lift 30")
    hand.apply()
    assert err.getvalue() == "" and out.getvalue().count("\n") == 4, out.getvalue()
    for _ in range(250):  # half a second of physics
        world.step()
    q = world.positions()
    assert abs(q[1] - math.radians(30)) < 1e-9
    assert all(abs(q[i] - s.neutral) < 1e-9 for i, s in enumerate(ARM.servos) if i != 1)
    # the encoder shows the injected mounting: offset 120 on servo 2
    assert world.servos[1].present_steps == rad_to_steps(lift, ServoCalibration(2, 120, 1), math.radians(30), world.step_rad)
    hand.put("release all")
    hand.apply()
    for _ in range(250):
        world.step()
    assert abs(world.positions()[1] - math.radians(30)) > math.radians(2), "a released limp joint sags"


def test_hand_commands_answer_one_line_each() -> None:
    world, hand, out, err = _limp_world()
    for line in ("elbow_flex 999", "4 -10", "show", "", "# a comment", "pose nowhere", "wrist_flex x", "knee 3",
                 "release", "help"):
        hand.put(line)
    hand.apply()
    said = out.getvalue().splitlines()
    assert said[0].startswith("hand: holds elbow_flex at ") and "(its range ends at" in said[0]
    assert said[1] == "hand: holds wrist_flex at -10.0 deg"
    assert said[2].startswith("hand: shoulder_pan ") and "wrist_flex -10.0 deg (held)" in said[2]
    assert said[3].startswith("hand: NAME|ID DEG") and len(said) == 4
    bad = err.getvalue().splitlines()
    assert len(bad) == 4 and all(x.startswith("hand: ") for x in bad), bad
    assert "no pose 'nowhere'" in bad[0] and "not an angle" in bad[1] and "no joint 'knee'" in bad[2]


def test_a_servo_with_torque_on_is_not_held() -> None:
    world, hand, out, _ = _limp_world()
    world.servos[0].torque = True
    assert "its torque is on" in (hand.command("shoulder_pan 40") or "")


# --- the two-terminal walk-through --------------------------------------------------------------------------


class _Proc:
    """A process whose stdout is collected by a thread; ``wait_for(text)`` waits until it has said it."""

    def __init__(self, args: list[str], env: dict[str, str]) -> None:
        self.p = subprocess.Popen(args, cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  stderr=subprocess.STDOUT, text=True, bufsize=1, env=env)
        self.text = ""
        self._cv = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.p.stdout is not None
        while True:
            ch = self.p.stdout.read(1)
            if not ch:
                return
            with self._cv:
                self.text += ch
                self._cv.notify_all()

    def wait_for(self, text: str, after: int = 0, timeout: float = 60) -> int:
        with self._cv:
            assert self._cv.wait_for(lambda: text in self.text[after:], timeout), (text, self.text[after:])
            return self.text.index(text, after) + len(text)

    def send(self, line: str) -> None:
        assert self.p.stdin is not None
        self.p.stdin.write(line + "\n")
        self.p.stdin.flush()


def test_two_terminal_walk_through_recovers_offset_and_reversal(tmp_path: Path) -> None:
    robots = tmp_path / "robots"
    shutil.copytree(BUILTIN_DIR / "arm", robots / "arm", ignore=shutil.ignore_patterns("__pycache__"))
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    plant = _Proc([sys.executable, "-m", "firmware_sim.plant", "--robot", "arm", "--offset", "2=120", "--reverse", "3",
                   "--hand", "--lockstep"], env)
    cal = None
    try:
        end = plant.wait_for("plant: servo bus on ")
        pty = plant.text[end:plant.wait_for("\n", end) - 1].strip()
        said = plant.wait_for("hand: NAME|ID DEG")

        def hand(line: str, dwell: float = 0.15) -> None:
            nonlocal said
            plant.send(line)
            said = plant.wait_for("\n", plant.wait_for("hand: ", said))
            time.sleep(dwell)  # the command reads every position every 20 ms while the range is recorded

        # the command as `ghostshell robots calibrate arm --servo-bus PTY --robots-dir DIR`, its SDK given the
        # answer time a USB adapter's latency timer would (as tests/cli/test_calibrate.py does): two busy
        # processes on a loaded machine are not always scheduled within the SDK's default 16 ms
        cal = _Proc([sys.executable, "-c", "import sys, scservo_sdk.port_handler as p, host.cli; p.LATENCY_TIMER = 100; "
                     "sys.exit(host.cli.main(sys.argv[1:]))", "robots", "calibrate", "arm", "--servo-bus", pty,
                     "--robots-dir", str(robots)], env)
        at = cal.wait_for("Put the robot in this pose and press Enter: ")
        time.sleep(0.5)  # limp: the arm sags meanwhile
        hand("pose zero")
        cal.send("")
        for s in ARM.servos:  # direction: a little towards its positive direction
            at = cal.wait_for(f"  {s.name} (servo {s.id}): towards", at)
            hand(f"{s.name} 12")
            cal.send("")
        at = cal.wait_for("Press Enter when every joint has been to both ends: ", at)
        for s in ARM.servos:  # range: end stop to end stop, by way of the middle
            for deg in (0, math.degrees(s.min), 0, math.degrees(s.max), 0):
                hand(f"{s.name} {deg:.3f}", 0.15 if deg == 0 else 0.6)  # an end stop: long enough on a loaded machine
        cal.send("")
        assert cal.p.wait(60) == 0, cal.text
    finally:
        for p in (plant, cal):
            if p is not None and p.p.poll() is None:
                p.p.terminate()
                p.p.wait(10)
    assert "still moving" not in cal.text[cal.text.index("1/3"):], cal.text  # held: nothing sagged
    written = load_calibration(robots / "arm", list(ARM.servos))
    for s in ARM.servos:
        c = written.of(s)
        want = ServoCalibration(s.id, 120 if s.id == 2 else 0, -1 if s.id == 3 else 1)
        assert (c.offset_steps, c.direction) == (want.offset_steps, want.direction), (s.name, c)
        lo, hi = sorted(rad_to_steps(s, want, q, ARM.servos.model.resolution) for q in (s.min, s.max))
        assert (c.min_steps, c.max_steps) == (lo, hi), (s.name, c)
    assert (robots / "arm" / CALIBRATION_FILE).is_file() and STEP_CENTRE == 2048


@pytest.mark.parametrize("flag", ["--hand"])
def test_the_flag_is_in_the_help(flag: str) -> None:
    from firmware_sim.plant.server import parser

    assert flag in parser().format_help()
