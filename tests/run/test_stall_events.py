"""Stall events (issue 45 item 1): one rule for every servo and behaviour, a joint_move blocked short of
its target and a gripper closed on a cube alike (host.run.events, host.run.effort_limits).

The rule: for STALL_S the commanded target stays put, the servo stays more than STALL_DEG from it,
its effort stays at SATURATED of its actuator's limit pushing towards the target, and it moves slower
than STALL_SPEED_DPS. The end-to-end cases run the desk arm in lockstep: a joint_move of the shoulder
into the table, and a pick whose gripper closes on the cube."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from host.cli import main as cli_main
from host.run.effort_limits import effort_limits, mjcf_force_ranges
from host.run.events import STALL_S, EventMonitor
from robots.registry import load_robot

LIMIT = (-1.9, 1.9)


def _feed(q_deg: float, effort: float, target_deg: float = 90.0, speed_dps: float = 0.0,
          limits: list[tuple[float, float] | None] | None = None) -> list[dict[str, object]]:
    target = np.radians([target_deg])
    m = EventMonitor(["shoulder_lift"], floating=False, targets=lambda t_us: target,
                     limits=[LIMIT] if limits is None else limits, joints=["shoulder_lift_joint"])
    got = [e for t in np.arange(0.0, 1.5, 0.02)
           for e in m.feed(float(t), [math.radians(q_deg)], None, efforts=[effort],
                           velocities=[math.radians(speed_dps)])]
    assert all(e.kind == "stall" for e in got)
    return [dict(e.data) for e in got]


def test_two_degrees_short_with_the_effort_saturated_is_a_stall() -> None:
    got = _feed(88.0, 1.9)
    assert len(got) == 1
    d = got[0]
    assert (d["servo"], d["joint"], d["target_deg"], d["reached_deg"], d["error_deg"]) == \
        ("shoulder_lift", "shoulder_lift_joint", 90.0, 88.0, 2.0)
    assert d["effort_nm"] == 1.9 and d["limit_nm"] == 1.9 and d["for_s"] >= STALL_S - 1e-9


@pytest.mark.parametrize(("q_deg", "effort", "speed_dps", "why"), [
    (88.0, 1.2, 0.0, "effort below its limit: a servo holding a load, not blocked"),
    (88.0, -1.9, 0.0, "saturated pushing away from the target"),
    (89.5, 1.9, 0.0, "within STALL_DEG of the target"),
    (88.0, 1.9, 40.0, "still moving: catching up"),
])
def test_no_stall_unless_every_condition_holds(q_deg: float, effort: float, speed_dps: float, why: str) -> None:
    assert _feed(q_deg, effort, speed_dps=speed_dps) == [], why


def test_a_servo_without_a_known_limit_gets_no_stall() -> None:
    assert _feed(60.0, 5.0, limits=[None]) == []


def test_the_limit_of_the_side_it_pushes_on() -> None:
    got = _feed(-60.0, -0.95, target_deg=-10.0 - 60.0, limits=[(-0.95, 0.95)])  # a gripper closing: negative
    assert len(got) == 1 and got[0]["limit_nm"] == -0.95 and got[0]["error_deg"] == 10.0


def test_effort_limits_come_from_the_mjcf_actuators_and_their_default_classes(tmp_path: Path) -> None:
    arm = load_robot("arm")
    assert effort_limits(arm) == ((-1.9, 1.9),) * 5 + ((-0.95, 0.95),)  # the gripper_servo class: half
    (tmp_path / "acts.xml").write_text('<mujoco><actuator><motor name="m3" joint="j" forcerange="-3 3"/>'
                                       '<motor name="free" joint="j" forcelimited="false" forcerange="-1 1"/>'
                                       '</actuator></mujoco>', encoding="utf-8")
    (tmp_path / "m.xml").write_text(
        '<mujoco><default><position forcerange="-2 2"/><default class="weak"><position forcerange="-0.5 0.5"/>'
        '</default></default><actuator><position name="a" joint="j"/><position name="b" joint="j" class="weak"/>'
        '<position name="c" joint="j" class="weak" forcerange="-1 4"/></actuator><include file="acts.xml"/>'
        '</mujoco>', encoding="utf-8")
    assert mjcf_force_ranges(tmp_path / "m.xml") == {"a": (-2.0, 2.0), "b": (-0.5, 0.5), "c": (-1.0, 4.0),
                                                     "m3": (-3.0, 3.0), "free": None}


def _stalls(out: Path) -> list[str]:
    s = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert s["outcome"] == "done"
    return [e for e in s["extra"]["events"] if e.startswith("stall")]


@pytest.mark.parametrize(("xml", "servo", "target"), [
    ('<joint_move joint="shoulder_lift" deg="45" duration="1"/>', "shoulder_lift", "target 45.0 deg"),
    ('<pick object="red_cube"/>', "gripper", ""),
])
def test_a_blocked_joint_move_and_a_gripper_on_a_cube_both_report_a_stall(tmp_path: Path, xml: str, servo: str,
                                                                           target: str) -> None:
    """The shoulder swings into the table (it stops at ~37 deg of 45, pushing at 1.9 N*m): the old rule
    (15 deg off for 0.5 s, no effort) said nothing; the gripper closing on the cube said "stall"."""
    out = tmp_path / "run"
    assert cli_main(["run", "--robot", "arm", "--lockstep", "--no-live", "--no-plots",
                     "--out", str(out), "--xml", xml]) == 0
    stalls = _stalls(out)
    assert len(stalls) == 1 and f": {servo} stopped short of its target" in stalls[0], stalls
    assert target in stalls[0] and "N*m at its limit" in stalls[0]
