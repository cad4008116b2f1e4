"""Gaits and skills played in MuJoCo the way the board plays them: distances, angles, never falling."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robots.coco import load_servo_table
from robots.coco.motions import BEHAVIOURS, channel_of
from robots.coco.playback import Player

MAX_TILT_DEG = 30.0
MIN_HEIGHT_CM = 3.5  # torso centre; the torso is 4.4 cm thick, so its belly stays off the floor


def test_run_distance_20cm() -> None:
    p = Player()
    r = p.play(BEHAVIOURS["run_distance"](p.targets, distance=20.0))
    assert 15.0 <= r.forward_cm <= 25.0
    assert abs(r.left_cm) < 4.0 and abs(r.yaw_deg) < 10.0
    assert r.max_tilt_deg < MAX_TILT_DEG


def test_run_distance_backwards() -> None:
    p = Player()
    r = p.play(BEHAVIOURS["run_distance"](p.targets, distance=-20.0))
    assert -25.0 <= r.forward_cm <= -15.0 and abs(r.left_cm) < 4.0


@pytest.mark.parametrize("angle", [90.0, -90.0])
def test_rotate_90_each_way(angle: float) -> None:
    p = Player()
    r = p.play(BEHAVIOURS["rotate"](p.targets, angle=angle))
    assert 0.8 * abs(angle) <= math.copysign(1.0, angle) * r.yaw_deg <= 1.2 * abs(angle)
    assert math.hypot(r.forward_cm, r.left_cm) < 5.0  # in place
    assert r.max_tilt_deg < MAX_TILT_DEG


def test_square_closes() -> None:
    p = Player()
    p0, _ = p.base()
    yaw = 0.0
    for _ in range(4):
        yaw += p.play(BEHAVIOURS["run_distance"](p.targets, distance=20.0), hold_s=0.1).yaw_deg
        yaw += p.play(BEHAVIOURS["rotate"](p.targets, angle=-90.0), hold_s=0.1).yaw_deg
    p1, _ = p.base()
    assert 100 * math.hypot(*(p1 - p0)[:2]) < 10.0
    assert abs(yaw + 360.0) < 35.0


@pytest.mark.parametrize("direction,axis,sign", [("forward", 0, 1), ("backward", 0, -1), ("left", 1, 1),
                                                 ("right", 1, -1)])
def test_creep_goes_its_way_low(direction: str, axis: int, sign: int) -> None:
    p = Player()
    r = p.play(BEHAVIOURS["creep"](p.targets, direction=direction, duration=2.0))
    moved = (r.forward_cm, r.left_cm)
    assert sign * moved[axis] > 5.0 and abs(moved[1 - axis]) < 0.5 * abs(moved[axis])
    assert r.min_height_cm < 8.0  # lower than standing (9.3 cm)


def test_move_strides_backward_and_persistent_walk_keeps_going() -> None:
    p = Player()
    one = p.play(BEHAVIOURS["move_strides"](p.targets, direction="backward", times=2))
    assert one.forward_cm < -4.0
    p = Player()
    m = BEHAVIOURS["run_distance"](p.targets, persistent=True)
    r = p.play(m, loops=4)
    assert r.forward_cm > 20.0 and r.max_tilt_deg < MAX_TILT_DEG


@pytest.mark.parametrize("name", sorted(BEHAVIOURS))
def test_no_behaviour_makes_coco_fall(name: str) -> None:
    p = Player()
    r = p.play(BEHAVIOURS[name](p.targets))
    assert r.max_tilt_deg < MAX_TILT_DEG, f"{name} tilts {r.max_tilt_deg:.1f} deg"
    assert r.min_height_cm > MIN_HEIGHT_CM, f"{name} drops the body to {r.min_height_cm:.1f} cm"
    if channel_of(name) != "body":
        assert math.hypot(r.forward_cm, r.left_cm) < 0.5  # head and ears do not move the base
    elif name not in ("run_distance", "rotate", "move_strides", "creep"):
        assert math.hypot(r.forward_cm, r.left_cm) < 6.0, f"{name} wanders off"


@pytest.mark.parametrize("name,kw", [("single_leg_knock", {"leg": 3}), ("single_leg_knock", {"leg": 4}),
                                     ("arm_pull", {"direction": "left"}), ("sit", {"style": "dog"}),
                                     ("stand", {"posture": "forward"}), ("body_lean", {"direction": "right"}),
                                     ("creep", {"direction": "left", "speed": 100})])
def test_variants_do_not_fall(name: str, kw: dict) -> None:
    p = Player()
    r = p.play(BEHAVIOURS[name](p.targets, **kw))
    assert r.max_tilt_deg < MAX_TILT_DEG and r.min_height_cm > MIN_HEIGHT_CM


def test_lifted_leg_really_lifts() -> None:
    """single_leg_knock shifts the weight so the knocking foot leaves the floor."""
    p = Player()
    m = BEHAVIOURS["single_leg_knock"](p.targets, leg=2)
    knee = m.servos.index(load_servo_table().by_name("fl_knee").index)
    k = int(np.argmax(m.q[:, knee]))  # knee at its highest: shifted and lifted
    p.play(type(m)(m.servos, m.t[: k + 1], m.q[: k + 1]), hold_s=0.05)
    feet = p.data.site_xpos[p.cm.foot_site_ids, 2] * 100
    assert feet[1] > 4.0 and np.all(feet[[0, 2, 3]] < 1.5)
