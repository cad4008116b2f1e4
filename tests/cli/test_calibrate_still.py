"""``ghostshell robots calibrate``'s reference pose: a joint still moving when it is read (a limp joint sagging
under gravity, a user saw offsets of +298 and +708 steps with none injected) is named in one warning line
before the offset is taken (from the later of two readings)."""

from __future__ import annotations

from host.calibration.procedure import STILL_STEPS, calibrate, still_warning
from robots.hardware import Hardware
from robots.loader import load_robot_dir
from tests.cli.test_calibrate import ROBOT, _FakeBus, robots_dir  # noqa: F401 - fixture


class _Sagging(_FakeBus):
    """Servo 2 sinks 7 steps a reading until the user starts the direction step; servo 4 jitters one step."""

    def __init__(self, robot) -> None:
        super().__init__(robot)
        self.sagging = True

    def position(self, servo_id: int) -> int:
        if self.sagging and servo_id == 2:
            self.pos[2] -= 7
        if servo_id == 4:
            self.pos[4] ^= 1  # encoder noise: not "moving"
        return super().position(servo_id)


def test_a_joint_still_moving_in_the_reference_pose_is_named(robots_dir) -> None:  # noqa: F811
    robot = load_robot_dir(robots_dir / ROBOT)
    bus = _Sagging(robot)
    said: list[str] = []
    asked: list[str] = []

    def ask(prompt: str) -> str:
        asked.append(prompt)
        if len(asked) == 2:
            bus.sagging = False
        if 2 <= len(asked) <= 1 + len(bus.pos):
            bus.pos[len(asked) - 1] += 100
        if len(asked) == 2 + len(bus.pos):
            for sid in bus.pos:
                bus.pos[sid] += 300
        return ""

    try:
        calibrate(robot, bus, Hardware(), ask=ask, say=said.append, poll_s=0.001, still_s=0.01)
    except Exception:  # noqa: BLE001 - the range checks may refuse this made-up robot; the warning came first
        pass
    warnings = [x for x in said if x.startswith("warning: still moving")]
    assert len(warnings) == 1, said
    assert "servo 2 (shoulder_lift) -7 steps in 0.01 s" in warnings[0] and "servo 4" not in warnings[0]
    assert "\n" not in warnings[0] and said.index(warnings[0]) < len(said)
    assert asked[0].startswith("Put the robot in this pose")


def test_still_joints_give_no_warning() -> None:
    from robots.registry import load_robot

    servos = list(load_robot("arm").servos)
    first = [2048 + i for i in range(len(servos))]
    assert still_warning(servos, first, [p + STILL_STEPS for p in first], 0.2) is None
    line = still_warning(servos, first, [first[0] + 298, *first[1:]], 0.2)
    assert line is not None and line.startswith("warning: still moving while the reference pose was read "
                                                "(servo 1 (shoulder_pan) +298 steps in 0.2 s)")
