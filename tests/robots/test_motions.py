"""Motion generators: the Motion contract, joint and speed limits, loops, durations, errors.

Pure numpy (no physics): every behaviour is generated from random valid starts and parameters.
"""

from __future__ import annotations

import inspect
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robots.coco import load_poses, load_servo_table
from robots.coco.interface import stubs
from robots.coco.motions import (
    BEHAVIOURS,
    CHANNEL_SERVOS,
    EAR_STATES,
    Motion,
    channel_of,
    channel_servos,
    rest_pose,
    transition,
)
from robots.coco.trajectory import limits

LO, HI, VMAX = limits()
STAND = np.array(load_poses()["stand"])

unit = st.integers(0, 100)
secs = st.floats(0.0, 6.0)
times = st.integers(1, 4)
PARAMS: dict[str, st.SearchStrategy[dict]] = {
    "stand": st.fixed_dictionaries({"posture": st.sampled_from(["normal", "forward", "backward"]),
                                    "duration": secs}),
    "sit": st.fixed_dictionaries({"style": st.sampled_from(["normal", "dog"]), "duration": secs}),
    "push_up": st.fixed_dictionaries({"duration": secs, "times": times}),
    "wave": st.fixed_dictionaries({"times": times, "speed": unit, "amplitude": unit}),
    "chest_expansion_exercise": st.fixed_dictionaries({"times": times}),
    "fly_rub_hands": st.fixed_dictionaries({"times": times}),
    "body_lean": st.fixed_dictionaries({"direction": st.sampled_from(["forward", "backward", "left", "right"]),
                                        "duration": secs}),
    "run_distance": st.fixed_dictionaries({"distance": st.floats(-300, 300), "speed": unit, "amplitude": unit}),
    "rotate": st.fixed_dictionaries({"angle": st.floats(-720, 720)}),
    "move_strides": st.fixed_dictionaries({"direction": st.sampled_from(["forward", "backward"]), "times": times}),
    "creep": st.fixed_dictionaries({"direction": st.sampled_from(["forward", "backward", "left", "right"]),
                                    "speed": unit, "duration": secs}),
    "wriggle": st.fixed_dictionaries({"duration": secs}),
    "single_leg_knock": st.fixed_dictionaries({"leg": st.integers(1, 4), "times": times, "speed": unit}),
    "shake_ass": st.fixed_dictionaries({"speed": unit, "times": times, "amplitude": unit}),
    "shake_like_dog": st.fixed_dictionaries({"duration": secs}),
    "arm_pull": st.fixed_dictionaries({"direction": st.sampled_from(["left", "right", "both"]), "speed": unit,
                                       "times": times}),
    "arm_knock": st.fixed_dictionaries({"speed": unit, "times": times}),
    "head_act": st.fixed_dictionaries({"action": st.sampled_from(["nod", "shake"]), "duration": secs}),
    "head_pose": st.fixed_dictionaries({"yaw": st.floats(-90, 90), "pitch": st.floats(-30, 30)}),
    "shake_ear": st.fixed_dictionaries({"duration": secs}),
    "ear_state": st.fixed_dictionaries({"state": st.sampled_from(sorted(EAR_STATES)), "duration": secs}),
    "ear_swing": st.fixed_dictionaries({"side": st.sampled_from(["left", "right"]),
                                        "start_angle": st.floats(-60, 60), "end_angle": st.floats(-60, 60),
                                        "speed": unit, "duration": secs}),
}
starts = st.lists(st.floats(0.0, 1.0), min_size=12, max_size=12).map(lambda u: LO + (HI - LO) * np.array(u))


def check_motion(m: Motion, start: np.ndarray, channel: str) -> None:
    assert m.servos == CHANNEL_SERVOS[channel]
    idx = list(m.servos)
    assert m.t.ndim == 1 and m.t[0] == 0.0 and np.all(np.diff(m.t) > 0)
    assert m.q.shape == (len(m.t), len(idx)) and np.all(np.isfinite(m.q))
    np.testing.assert_allclose(m.q[0], start[idx], atol=1e-12)
    assert np.all(m.q >= LO[idx] - 1e-9) and np.all(m.q <= HI[idx] + 1e-9)
    speed = np.abs(np.diff(m.q, axis=0)) / np.diff(m.t)[:, None]
    assert np.all(speed <= VMAX[idx] * (1 + 1e-6)), f"max speed ratio {np.max(speed / VMAX[idx]):.3f}"
    if m.loop_from is not None:
        assert 0.0 <= m.loop_from <= m.t[-1]
        k = int(np.searchsorted(m.t, m.loop_from))
        assert m.t[k] == pytest.approx(m.loop_from)
        np.testing.assert_allclose(m.q[k], m.q[-1], atol=1e-9)  # seamless loop


@pytest.mark.parametrize("name", sorted(BEHAVIOURS))
@settings(max_examples=30, deadline=None)
@given(start=starts, params=st.data(), persistent=st.booleans())
def test_every_behaviour_respects_contract_limits_and_speeds(name: str, start: np.ndarray, params: st.DataObject,
                                                             persistent: bool) -> None:
    kw = params.draw(PARAMS[name])
    m = BEHAVIOURS[name](start, persistent=persistent, **kw)
    check_motion(m, start, channel_of(name))
    if persistent:
        assert m.loop_from is not None
    else:
        assert m.loop_from is None


def test_every_behaviour_has_params_strategy_and_interface_signature() -> None:
    assert set(PARAMS) == set(BEHAVIOURS)
    # every stub mapping to a motion behaviour passes parameters the generator accepts
    for vocab in ("paper", "coco"):
        for stub_name, (fn, info) in stubs(vocab).items():
            if info.channel not in CHANNEL_SERVOS:
                continue
            gen = BEHAVIOURS[info.behaviour]
            assert channel_of(info.behaviour) == info.channel, stub_name
            accepted = set(inspect.signature(gen).parameters)
            names = {info.rename.get(p, p) for p in inspect.signature(fn).parameters if p != "self"}
            assert names | set(info.fixed) <= accepted, (stub_name, names - accepted)
            defaults = {info.rename.get(k, k): p.default for k, p in inspect.signature(fn).parameters.items()
                        if k != "self"}
            check_motion(gen(STAND, **defaults, **info.fixed), STAND, info.channel)


def test_postures_hold_and_reach_pose() -> None:
    m = BEHAVIOURS["sit"](STAND, persistent=True, style="normal")
    assert m.loop_from == m.t[-1]
    np.testing.assert_allclose(m.q[-1], np.array(load_poses()["sit"])[list(CHANNEL_SERVOS["body"])])
    m = BEHAVIOURS["head_pose"](STAND, persistent=True, yaw=-40.0, pitch=10.0)
    np.testing.assert_allclose(np.degrees(m.q[-1]), [-40.0, 10.0])
    assert m.loop_from == m.t[-1]
    m = BEHAVIOURS["ear_state"](STAND, state="down", duration=2.0)
    assert m.t[-1] == pytest.approx(2.0)
    np.testing.assert_allclose(np.degrees(m.q[-1]), EAR_STATES["down"])


def test_head_pose_sign_convention() -> None:
    yaw = load_servo_table().by_name("head_yaw").index
    m = BEHAVIOURS["head_pose"](STAND, yaw=-30.0)
    assert m.q[-1][CHANNEL_SERVOS["head"].index(yaw)] < 0  # yaw < 0 looks right


@pytest.mark.parametrize("name,kw", [("head_act", {"action": "nod", "duration": 3.0}),
                                     ("head_act", {"action": "shake", "duration": 1.0}),
                                     ("shake_ear", {"duration": 2.0}),
                                     ("wriggle", {"duration": 3.0}),
                                     ("shake_like_dog", {"duration": 2.0}),
                                     ("push_up", {"duration": 4.0})])
def test_durations_are_respected(name: str, kw: dict) -> None:
    m = BEHAVIOURS[name](STAND, **kw)
    assert kw["duration"] - 0.05 <= m.t[-1] <= kw["duration"] + 1.5


def test_times_scale_the_motion_and_gestures_return_home() -> None:
    one = BEHAVIOURS["push_up"](STAND, times=1)
    three = BEHAVIOURS["push_up"](STAND, times=3)
    assert three.t[-1] == pytest.approx(3 * one.t[-1], rel=0.05)
    knee = list(CHANNEL_SERVOS["body"]).index(load_servo_table().by_name("fr_knee").index)
    dips = np.sum(np.diff(np.sign(np.diff(three.q[:, knee]))) < 0)  # local maxima of the knee: one per push-up
    assert dips == 3
    start = STAND.copy()
    start[list(CHANNEL_SERVOS["head"])] = np.radians([20.0, 10.0])
    nod = BEHAVIOURS["head_act"](start, action="nod")
    np.testing.assert_allclose(nod.q[-1], start[list(CHANNEL_SERVOS["head"])])
    assert np.ptp(nod.q[:, 1]) > math.radians(20)  # pitch moves, yaw stays
    assert np.ptp(nod.q[:, 0]) < 1e-9


def test_transition_respects_speed_and_cap() -> None:
    servos = CHANNEL_SERVOS["body"]
    target = np.array(load_poses()["crouch"])
    m = transition(STAND, target, servos)
    check_motion(m, STAND, "body")
    np.testing.assert_allclose(m.q[-1], target[list(servos)])
    slow = transition(STAND, target, servos, max_speed=math.radians(50))
    assert slow.t[-1] > 2 * m.t[-1]
    assert np.max(np.abs(np.diff(slow.q, axis=0)) / np.diff(slow.t)[:, None]) <= math.radians(50) * 1.001
    head = CHANNEL_SERVOS["head"]
    per_servo = transition(np.radians([30.0, 5.0]), np.radians([-10.0, 0.0]), head)  # per-servo vectors
    np.testing.assert_allclose(np.degrees(per_servo.q[[0, -1]]), [[30.0, 5.0], [-10.0, 0.0]], atol=1e-9)
    outside = STAND.copy()
    outside[head[0]] = 2.0  # beyond the 90 deg yaw limit: a reset still works, from the limit
    m = transition(outside, STAND, head)
    assert m.q[0][0] == pytest.approx(LO[head[0]] if outside[head[0]] < 0 else HI[head[0]])
    with pytest.raises(ValueError, match="servos"):
        transition(STAND, target, (12,))
    with pytest.raises(ValueError, match="max_speed"):
        transition(STAND, target, servos, max_speed=0.0)


def test_rest_pose_and_channels() -> None:
    assert len(CHANNEL_SERVOS["body"]) == 8 and set(CHANNEL_SERVOS["body"]) == set(range(8))
    names = load_servo_table().names
    assert [names[i] for i in CHANNEL_SERVOS["head"]] == ["head_yaw", "head_pitch"]
    assert [names[i] for i in CHANNEL_SERVOS["ears"]] == ["ear_left", "ear_right"]
    np.testing.assert_allclose(rest_pose("body"), STAND[:8])
    assert channel_of("head_act") == "head" and channel_servos("head") == CHANNEL_SERVOS["head"]
    assert channel_of("ear_swing") == "ears" and channel_of("rotate") == "body"
    with pytest.raises(ValueError, match="known"):
        channel_of("face_emo")
    with pytest.raises(ValueError, match="channels"):
        rest_pose("face")


@pytest.mark.parametrize("name,kw,match", [
    ("stand", {"posture": "sideways"}, "normal, forward, backward"),
    ("ear_state", {"state": "sideways"}, "valid"),
    ("single_leg_knock", {"leg": 5}, "leg must be"),
    ("wave", {"times": 0}, "times"),
    ("shake_ass", {"speed": 150}, "0..100"),
    ("run_distance", {"distance": float("nan")}, "finite"),
    ("head_act", {"duration": -1.0}, ">= 0"),
])
def test_bad_parameters_are_clear_errors(name: str, kw: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        BEHAVIOURS[name](STAND, **kw)


def test_bad_start_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="12"):
        BEHAVIOURS["stand"](np.zeros(5))
    bad = STAND.copy()
    bad[0] = 3.0
    with pytest.raises(ValueError, match="fr_hip"):
        BEHAVIOURS["stand"](bad)


def test_motion_at_loops() -> None:
    m = BEHAVIOURS["head_act"](STAND, persistent=True, action="nod")
    period = m.t[-1] - m.loop_from
    np.testing.assert_allclose(m.at(m.t[-1] + 0.3 * period), m.at(m.loop_from + 0.3 * period), atol=1e-12)


#: Behaviours whose ``duration`` repeats a gesture (postures' and peripherals' durations are holds).
REPEATING_DURATION = {"head_act", "shake_ear", "ear_swing", "push_up", "wriggle", "shake_like_dog", "creep"}


@pytest.mark.parametrize("vocabulary", ["paper", "coco"])
def test_one_call_is_one_gesture_by_default_in_both_vocabularies(vocabulary: str) -> None:
    for name, (fn, info) in stubs(vocabulary).items():
        params = inspect.signature(fn).parameters
        if "times" in params:
            assert params["times"].default == 1, f"{vocabulary}:{name}: times must default to one gesture"
        if "duration" in params and info.behaviour in REPEATING_DURATION:
            assert params["duration"].default == 0.0, f"{vocabulary}:{name}: no duration must mean one gesture"


def _extrema(x: np.ndarray, lo: bool) -> int:
    """Strict local minima (``lo``) or maxima of a sampled joint trajectory deeper than 5 degrees."""
    d = np.diff(np.sign(np.diff(x)))
    idx = np.flatnonzero(d > 0 if lo else d < 0) + 1
    ref = x[0]
    return int(sum(abs(x[i] - ref) > math.radians(5.0) for i in idx))


@pytest.mark.parametrize("name,kw,col,lo", [
    ("head_act", {"action": "nod"}, 1, True),     # a nod dips the pitch once
    ("head_act", {"action": "shake"}, 0, False),  # a shake turns the yaw out once
    ("shake_ear", {}, 0, False),                  # a flap lifts the ear once
])
def test_gesture_counts_follow_duration(name: str, kw: dict, col: int, lo: bool) -> None:
    one = BEHAVIOURS[name](STAND, **kw)
    assert _extrema(one.q[:, col], lo) == 1
    assert one.t[-1] < 1.5
    three_s = BEHAVIOURS[name](STAND, duration=3.0, **kw)
    assert three_s.t[-1] == pytest.approx(3.0, abs=0.6)
    assert _extrema(three_s.q[:, col], lo) == pytest.approx(3.0 / one.t[-1], abs=1.5)


@pytest.mark.parametrize("name,kw", [("head_act", {"action": "nod"}), ("shake_ear", {}), ("move_strides", {})])
def test_ease_in_starts_from_rest_without_speeding_up(name: str, kw: dict) -> None:
    from robots.coco.trajectory import EASE_IN_S, ease_in

    m = BEHAVIOURS[name](STAND, **kw)
    e = ease_in(m)
    assert e.t[-1] == pytest.approx(m.t[-1] + EASE_IN_S / 2) and np.all(np.diff(e.t) > 0)
    np.testing.assert_allclose(e.q[0], m.q[0])
    np.testing.assert_allclose(e.q[-1], m.q[-1])
    first = np.abs(e.at(0.01) - m.q[0]).max()
    assert first <= 0.03 * np.abs(m.at(0.01) - m.q[0]).max() + 1e-12  # almost the current pose
    speed = lambda x: np.max(np.abs(np.diff(x.q, axis=0)) / np.diff(x.t)[:, None])  # noqa: E731
    assert speed(e) <= speed(m) * (1 + 1e-9)


def test_ease_in_keeps_a_loop_that_starts_inside_the_ramp() -> None:
    from robots.coco.trajectory import ease_in

    m = Motion((9,), np.array([0.0, 0.01, 0.02]), np.array([[0.0], [0.1], [0.0]]), loop_from=0.0)
    assert ease_in(m) is m


def test_an_ear_swing_over_a_subnormal_angle_is_one_cycle() -> None:
    """Hypothesis found it in CI: end_angle 2.2e-313 rad made the speed-limited period subnormal and
    ``duration / min_period`` infinite (OverflowError converting it to a cycle count)."""
    m = BEHAVIOURS["ear_swing"](LO + 0.0 * (HI - LO), persistent=False, side="left", start_angle=0.0,
                                end_angle=2.2250738585e-313, speed=0, duration=1.0)
    assert m.duration > 0
