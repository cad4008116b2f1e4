"""The desk arm as a package: it loads and agrees with its MJCF, its IK is exact against MuJoCo's
forward kinematics, every behaviour stays inside the joint and speed limits and above the table,
its stubs map onto its behaviours, and its tasks are well formed."""

from __future__ import annotations

import itertools
import json
import math
from typing import Any, get_args

import mujoco
import numpy as np
import pytest

from host.runtime.binding import robot_registry
from host.shell import Shell
from host.shell.prompt import render_prompt
from robots.arm import behaviours as B
from robots.arm import interface
from robots.arm.kinematics import DOWN, ArmGeometry, Unreachable
from robots.motion import Motion
from robots.registry import load_robot

ARM = load_robot("arm")
GEOM = B.geometry()
LO, HI, VMAX = B.LIMITS.lo, B.LIMITS.hi, B.LIMITS.vmax
NAMES = ARM.servos.names
CATEGORIES = {"atomic", "sequential", "parallel", "sequential_parallel_composite", "lifecycle_scoped_termination"}


def _model() -> tuple[mujoco.MjModel, mujoco.MjData, list[int]]:
    m = mujoco.MjModel.from_xml_path(str(ARM.mjcf))
    return m, mujoco.MjData(m), [int(m.joint(s.joint).qposadr[0]) for s in ARM.servos]


# --- the package ---------------------------------------------------------------------------------


def test_package_loads_with_its_shape() -> None:
    assert ARM.name == "arm" and ARM.servo_count == 6 and not ARM.base.floating
    assert NAMES == ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")
    assert {c: ARM.channels[c].servos for c in ARM.channels} == {"arm": (0, 1, 2, 3, 4), "gripper": (5,)}
    p = ARM.peripherals
    assert p.camera == "wrist_cam" and p.camera_label == "wrist camera" and p.speaker and not p.screen
    assert ARM.default_scene == "table" and set(ARM.scenes) == {"empty", "table"}
    assert {"home", "rest"} <= set(ARM.poses) and ARM.safe_pose == "rest" and ARM.start_pose == "home"
    assert ARM.demo_task in ARM.tasks and set(ARM.view) == {"distance_m", "azimuth_deg", "elevation_deg", "lookat_z"}


def test_servo_model_is_an_sts3215() -> None:
    model = ARM.servos.model
    assert model.model == "STS3215" and model.stall_torque == 1.9
    assert math.isclose(math.degrees(model.resolution), 360 / 4096)
    assert all(math.isclose(math.degrees(s.max_speed), 300.0) for s in ARM.servos)  # ~0.2 s / 60 deg


def test_mjcf_agrees_with_the_servo_table() -> None:
    """Ranges (the loader checks them too), position actuators at the STS3215's stall torque (the
    gripper at half, as LeRobot limits it), fixed base, wrist camera."""
    m, _, _ = _model()
    for s in ARM.servos:
        j, a = m.joint(s.joint), m.actuator(s.actuator)
        assert np.allclose(np.degrees(j.range), np.degrees([s.min, s.max]), atol=0.05), s.name
        assert int(a.trnid[0]) == j.id and -float(a.biasprm[1]) == float(a.gainprm[0]) > 0
        stall = 0.95 if s.name == "gripper" else 1.9
        assert np.allclose(a.forcerange, [-stall, stall]), s.name
        assert bool(a.forcelimited)
    assert not any(int(t) == int(mujoco.mjtJoint.mjJNT_FREE) for t in m.jnt_type)  # bolted down
    assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, "wrist_cam") >= 0


def test_table_scene_has_two_cubes_within_reach() -> None:
    cm = ARM.model("table")
    assert [o.name for o in cm.objects] == ["red_cube", "blue_cube"]
    for o in ARM.scene("table").objects:
        if o.free:
            assert o.shape == "box" and o.size == (0.0125, 0.0125, 0.0125) and o.mass is not None and o.mass <= 0.03
            B._down_pose((o.pos[0], o.pos[1], o.pos[2]))  # reachable from above (else Unreachable)
        else:
            assert o.name.startswith("table")


def test_poses_are_inside_the_ranges_and_above_the_table() -> None:
    for name, q in ARM.poses.items():
        assert np.all(np.asarray(q) >= LO - 1e-9) and np.all(np.asarray(q) <= HI + 1e-9), name
        assert GEOM.forward(np.asarray(q))[0][2] > 0.03, name


# --- kinematics -----------------------------------------------------------------------------------


def test_geometry_is_the_so101s() -> None:
    """Link lengths from the SO-101's public link offsets (rounded), read from the MJCF."""
    assert (GEOM.l1, GEOM.l2) == (0.116, 0.135)
    assert math.isclose(GEOM.lift_z, 0.0624 + 0.0542) and GEOM.lift_r == 0.0304


POINTS = [(x, y, z) for x, y, z in itertools.product((0.12, 0.17, 0.22, 0.26), (-0.15, -0.05, 0.0, 0.08, 0.16),
                                                      (0.015, 0.04, 0.07))
          if math.hypot(x, y) >= 0.12]


def test_ik_round_trips_through_mujoco_forward_kinematics() -> None:
    """Joint angles from the IK put MuJoCo's grasp site on the target (within 1 mm; the closed form
    is exact), the hand straight down and the jaws square to the world axes."""
    m, d, adr = _model()
    site = m.site("grasp").id
    checked = 0
    for p in POINTS:
        pan = math.atan2(p[1], p[0])
        try:
            q = GEOM.solve(p, DOWN, GEOM.square_roll(pan))
        except Unreachable:
            continue
        d.qpos[adr[:5]] = q
        mujoco.mj_kinematics(m, d)
        got = d.site_xpos[site]
        assert np.linalg.norm(got - p) < 1e-3, (p, got)
        axes = d.site_xmat[site].reshape(3, 3)
        assert np.allclose(axes[:, 0], [0, 0, -1], atol=1e-6)  # the hand points down
        jaw = axes[:, 1]  # the jaws close along a world axis (square to an unrotated cube)
        assert max(abs(jaw[0]), abs(jaw[1])) > 1 - 1e-6, jaw
        assert np.allclose(GEOM.forward(q)[0], got, atol=1e-9)
        checked += 1
    assert checked >= 30


def test_ik_at_other_pitches_round_trips() -> None:
    m, d, adr = _model()
    site = m.site("grasp").id
    for pitch_deg, p in [(0, (0.3, 0.0, 0.15)), (45, (0.2, 0.1, 0.1)), (60, (0.18, 0.0, 0.16)), (80, (0.15, -0.1, 0.05))]:
        q = GEOM.solve(p, math.radians(pitch_deg))
        d.qpos[adr[:5]] = q
        mujoco.mj_kinematics(m, d)
        assert np.linalg.norm(d.site_xpos[site] - p) < 1e-3
        assert math.isclose(GEOM.forward(q)[1], math.radians(pitch_deg), abs_tol=1e-9)


@pytest.mark.parametrize("p, why", [((0.6, 0.0, 0.05), "out of reach"), ((0.16, 0.0, 0.2), "wrist_flex"),
                                    ((-0.2, 0.0, 0.05), "shoulder_pan")])
def test_ik_refuses_what_it_cannot_reach(p: tuple[float, float, float], why: str) -> None:
    with pytest.raises(Unreachable, match=why):
        GEOM.solve(p)


def test_square_roll() -> None:
    assert GEOM.square_roll(0.0) == 0.0
    assert math.isclose(GEOM.square_roll(math.radians(20)), math.radians(20))
    assert math.isclose(GEOM.square_roll(math.radians(60)), math.radians(-30))
    assert math.isclose(GEOM.square_roll(math.radians(60), math.radians(30)), math.radians(30))


# --- behaviours ------------------------------------------------------------------------------------


def _after(gen: str, start: np.ndarray, **params: Any) -> np.ndarray:
    m = B.BEHAVIOURS[gen](start, **params)
    q = start.copy()
    q[list(m.servos)] = m.q[-1]
    return q


HOME = np.array(ARM.pose("home"))
HOLDING = _after("pick", HOME, object="red_cube")
STARTS = {"home": HOME, "rest": np.array(ARM.pose("rest")), "up": np.array(ARM.pose("up")), "holding": HOLDING}

CASES: list[tuple[str, dict[str, Any]]] = [
    ("wave", {}), ("wave", {"times": 3}), ("wave", {"duration": 2.5}), ("nod", {}), ("nod", {"times": 2}),
    ("nod", {"duration": 1.0}), ("shake", {}), ("shake", {"duration": 3.0}), ("snap", {}), ("snap", {"times": 3}),
    ("grip", {}), ("release", {}),
    *[("point_at", {"target": t}) for t in get_args(interface.PlaceName)],
    *[("pick", {"object": o}) for o in get_args(interface.ObjectName)],
    *[("place", {"object": o, "on": t}) for o in get_args(interface.ObjectName) for t in get_args(interface.PlaceName)
      if t != o],
    ("pose", {"name": "rest"}), ("joint_move", {"joint": "wrist_roll", "deg": 90.0}),
]


def _check_motion(m: Motion, start: np.ndarray, what: str) -> None:
    sel = list(m.servos)
    assert m.t[0] == 0.0 and np.all(np.diff(m.t) > 0), what
    assert np.allclose(m.q[0], start[sel], atol=1e-9), f"{what}: does not start where the servos are"
    assert np.all(m.q >= LO[sel] - 1e-9) and np.all(m.q <= HI[sel] + 1e-9), f"{what}: leaves a joint range"
    speed = np.abs(np.diff(m.q, axis=0)) / np.diff(m.t)[:, None]
    assert np.all(speed <= VMAX[sel] * (1 + 1e-6)), f"{what}: {np.degrees(speed.max()):.0f} deg/s"
    # the jaw tips (11 mm past the grasp point along the hand) never go into the table
    full = np.tile(start, (len(m.t), 1))
    full[:, sel] = m.q
    low = min(GEOM.forward(q)[0][2] - 0.011 * math.sin(GEOM.forward(q)[1]) for q in full)
    assert low > 0.0005, f"{what}: the jaw tips reach {low * 1000:.1f} mm"


@pytest.mark.parametrize("start", sorted(STARTS))
@pytest.mark.parametrize("gen, params", CASES, ids=lambda v: str(v))
def test_every_behaviour_stays_inside_the_limits(gen: str, params: dict[str, Any], start: str) -> None:
    q0 = STARTS[start]
    for persistent in (False, True):
        m = ARM.behaviours[gen](q0, persistent=persistent, **params)
        _check_motion(m, q0, f"{gen}{params} from {start}{' (persistent)' if persistent else ''}")
        assert (m.loop_from is not None) == persistent


def test_channels_of_the_behaviours() -> None:
    arm, grip, both = (0, 1, 2, 3, 4), (5,), (0, 1, 2, 3, 4, 5)
    expect = {"wave": arm, "nod": arm, "shake": arm, "point_at": arm, "pick": both, "place": both,
              "grip": grip, "release": grip, "snap": grip}
    for name, servos in expect.items():
        assert B.BEHAVIOURS[name](HOME).servos == servos, name


def test_gestures_return_where_they_began_and_fill_their_duration() -> None:
    for gen in ("wave", "nod", "shake", "snap"):
        for params in ({}, {"times": 2}, {"duration": 3.0}):
            m = B.BEHAVIOURS[gen](HOME, **params)
            assert np.allclose(m.q[-1], HOME[list(m.servos)], atol=1e-9), (gen, params)
    for gen, setup in (("nod", 0.0), ("shake", 0.0), ("snap", 0.0)):
        assert abs(B.BEHAVIOURS[gen](HOME, duration=3.0).duration - 3.0) < 0.05 + setup, gen
    one, three = B.wave(HOME), B.wave(HOME, times=3)
    assert math.isclose(three.duration - one.duration, 2 * B.WAVE_PERIOD_S, rel_tol=1e-6)


def test_pick_goes_down_to_the_cube_and_closes_on_it() -> None:
    m = B.pick(HOME, object="blue_cube")
    cube = ARM.scene().object("blue_cube")
    points = np.array([GEOM.forward(q)[0] for q in m.q])
    lowest = int(np.argmin(points[:, 2]))
    assert np.allclose(points[lowest], (cube.pos[0], cube.pos[1], cube.pos[2] + B.GRASP_ABOVE_CENTRE_M), atol=1e-6)
    grip = np.degrees(m.q[:, 5])
    assert grip[lowest] >= B.OPEN_DEG - 1e-6 and grip[-1] == B.CLOSED_DEG  # open on the way down, closed at the end
    assert np.isclose(points[-1][2] - points[lowest][2], B.PICK_HOVER_M)  # lifted straight up
    assert np.allclose(points[-1][:2], points[lowest][:2], atol=1e-6)


def test_place_on_the_other_cube_lets_go_just_above_it() -> None:
    m = B.place(HOLDING, object="red_cube", on="blue_cube")
    blue = ARM.scene().object("blue_cube")
    points = np.array([GEOM.forward(q)[0] for q in m.q])
    lowest = int(np.argmin(points[:, 2]))
    top = blue.pos[2] + blue.size[2]
    assert np.isclose(points[lowest][2], top + B.DROP_M + 0.0125 + B.GRASP_ABOVE_CENTRE_M)
    assert np.allclose(points[lowest][:2], blue.pos[:2], atol=1e-6)
    assert np.degrees(m.q[-1, 5]) == B.RELEASE_DEG


@pytest.mark.parametrize("gen, params, match", [
    ("pick", {"object": "green_cube"}, "no object 'green_cube'"),
    ("place", {"object": "red_cube", "on": "moon"}, "no object or place 'moon'"),
    ("place", {"object": "red_cube", "on": "red_cube"}, "on itself"),
    ("point_at", {"target": "nowhere"}, "no object or place"),
    ("wave", {"times": 0}, "times"),
    ("nod", {"duration": -1.0}, "duration"),
    ("snap", {"duration": math.nan}, "duration"),
])
def test_bad_parameters_are_clear_errors(gen: str, params: dict[str, Any], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        B.BEHAVIOURS[gen](HOME, **params)


# --- the interface ----------------------------------------------------------------------------------


def test_name_types_are_the_scene_objects_and_places() -> None:
    objects = tuple(o.name for o in ARM.scene("table").objects if o.free)
    assert get_args(interface.ObjectName) == objects
    assert get_args(interface.PlaceName) == (*objects, *B.places())


class Recorder:
    """Records behaviour calls instead of moving the arm (the binding's translation is under test)."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, str, dict[str, Any]]] = []

    async def perform(self, behaviour: str, channel: str, args: dict[str, Any], call: Any) -> Any:
        self.calls.append((behaviour, channel, args))

    async def reset(self, behaviour: str, channel: str, call: Any) -> None:
        self.calls.append((f"reset:{behaviour}", channel, {}))

    async def speak(self, text: str, call: Any) -> Any:
        self.calls.append(("speak", "speech", {"text": text}))


@pytest.mark.anyio
@pytest.mark.parametrize("anyio_backend", ["asyncio"])
async def test_stubs_map_onto_the_behaviours(anyio_backend: str) -> None:
    rec = Recorder()
    shell = Shell(robot_registry(ARM, rec))
    result = await shell.run_text('<pick object="blue_cube"/><place object="blue_cube" on="left"/><grip/>'
                                  '<snap times="2"/><point_at target="front"/><wave duration="2"/><capture/>'
                                  '<play_bgm duration="1"/><pose name="rest"/>Hello.')
    assert result.error is None and all(r.outcome == "done" for r in result.timeline)
    assert ("pick", "arm", {"object": "blue_cube"}) in rec.calls
    assert ("place", "arm", {"object": "blue_cube", "on": "left"}) in rec.calls
    assert ("grip", "gripper", {}) in rec.calls and ("snap", "gripper", {"times": 2, "duration": 0.0}) in rec.calls
    assert ("point_at", "arm", {"target": "front"}) in rec.calls
    assert ("wave", "arm", {"times": 1, "duration": 2.0}) in rec.calls
    assert ("capture", "camera", {}) in rec.calls
    assert ("play_bgm", "bgm", {"duration": 1.0, "name": "happy", "volume": 60}) in rec.calls
    assert ("pose", "joints", {"name": "rest", "duration": 1.0}) in rec.calls
    assert ("speak", "speech", {"text": "Hello."}) in rec.calls


@pytest.mark.anyio
@pytest.mark.parametrize("anyio_backend", ["asyncio"])
@pytest.mark.parametrize("xml", ['<pick object="green_cube"/>', '<place on="moon"/>', '<wave times="0"/>',
                                 '<face_emo emo="happy"/>'])
async def test_the_mapper_refuses_what_the_arm_cannot_do(xml: str, anyio_backend: str) -> None:
    rec = Recorder()
    result = await Shell(robot_registry(ARM, rec)).run_text(xml)
    assert result.error is not None or any(r.outcome == "failed" for r in result.timeline)
    assert not [c for c in rec.calls if c[0] != "speak"]


def test_prompt_shows_the_arms_functions_and_no_face() -> None:
    text = render_prompt(robot_registry(ARM, Recorder()), format="xml")
    for name in ("<pick", "<place", "<point_at", "<wave", "<nod", "<grip", "<release", "<snap", "<capture", "<pose"):
        assert name in text, name
    assert "face_emo" not in text and "red_cube" in text and "wrist camera" in text


# --- tasks ------------------------------------------------------------------------------------------


def test_tasks_are_numbered_from_one_in_the_papers_modes() -> None:
    tasks = ARM.tasks
    assert sorted(tasks) == list(range(1, len(tasks) + 1)) and len(tasks) >= 10
    assert {t.category for t in tasks.values()} == CATEGORIES
    assert all(t.ground_truth for t in tasks.values())
    demo = tasks[ARM.demo_task]  # the demo picks a cube while it talks
    assert "<pick" in demo.ground_truth and "I am" in demo.ground_truth
    doc = json.loads(ARM.tasks_path.read_text())
    assert doc["tasks"][0]["id"] == 1


@pytest.mark.anyio
@pytest.mark.parametrize("anyio_backend", ["asyncio"])
async def test_every_ground_truth_maps_in_strict_mode(anyio_backend: str) -> None:
    for t in ARM.tasks.values():
        rec = Recorder()
        result = await Shell(robot_registry(ARM, rec)).run_text(t.ground_truth)
        assert result.error is None, (t.id, result.error)
        assert all(r.outcome == "done" for r in result.timeline), t.id
