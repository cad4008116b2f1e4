"""CoCo's motion library: one trajectory generator per body, head and ear behaviour.

Every generator has the signature ``gen(start, *, persistent=False, **params) -> Motion`` where
``start`` holds the current joint targets of all 12 servos (radians) and ``params`` are the
behaviour's parameters with the units and defaults of ``robots/coco/interface.py`` (degrees, cm,
seconds, speed/amplitude 0-100). The motion drives one channel's servos (:data:`CHANNEL_SERVOS`),
begins exactly at ``start``, stays inside the joint and speed limits, and

- finite form: one call = one gesture. Without ``duration``/``times`` (``duration`` 0, ``times``
  1) a repeating behaviour plays one gesture at its natural tempo; ``times`` plays that many
  repetitions and ``duration`` > 0 repeats the gesture to fill about that many seconds; then it
  settles (gestures return to where they began, body skills to the stand pose);
- persistent form: rhythmic behaviours end with one seamless cycle from ``loop_from`` (the mixer
  repeats it until released); postures end at the pose with ``loop_from == t[-1]`` (a hold).

Gaits live in :mod:`robots.coco.gaits`; this module holds the expressive skills and the registry.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from robots.coco import load_poses
from robots.coco import gaits
from robots.coco.gaits import HIP_COLS, KNEE_COLS, stand_body
from robots.coco.trajectory import (
    CHANNEL_SERVOS,
    DT,
    Motion,
    Track,
    check_choice,
    check_count,
    check_finite,
    check_start,
    limits,
    transition,
)

__all__ = [
    "BEHAVIOURS",
    "CHANNEL_SERVOS",
    "EAR_STATES",
    "Motion",
    "channel_of",
    "channel_servos",
    "rest_pose",
    "transition",
]

rad = math.radians
BODY, HEAD, EARS = CHANNEL_SERVOS["body"], CHANNEL_SERVOS["head"], CHANNEL_SERVOS["ears"]
#: Comfortable speeds for postures (rad/s), well under the servos' limits.
BODY_SPEED, HEAD_SPEED, EAR_SPEED = rad(150.0), rad(200.0), rad(300.0)
#: The slowest leg servo's speed limit (rad/s), from the servo table.
LEG_VMAX = float(limits()[2][list(BODY)].min())


def rest_pose(channel: str) -> np.ndarray:
    """The pose a channel returns to after a reset (the stand pose's values for its servos)."""
    servos = _servos(channel)
    return np.array(load_poses()["stand"])[list(servos)]


def channel_servos(channel: str) -> tuple[int, ...]:
    """0-based servo indices a motion channel (body, head, ears) drives."""
    return _servos(channel)


def _servos(channel: str) -> tuple[int, ...]:
    try:
        return CHANNEL_SERVOS[channel]
    except KeyError:
        raise ValueError(f"unknown channel {channel!r}; motion channels are {', '.join(CHANNEL_SERVOS)}") from None


def _unit(v: float, what: str) -> float:
    """A 0-100 parameter as a fraction (clear error when out of range)."""
    check_finite(**{what: v})
    if not 0 <= v <= 100:
        raise ValueError(f"{what} must be in 0..100, got {v}")
    return float(v) / 100.0


def _seconds(v: float, what: str = "duration") -> float:
    check_finite(**{what: v})
    if v < 0:
        raise ValueError(f"{what} must be >= 0 s, got {v}")
    return float(v)


def _rhythm(duration: float, period: float, min_period: float = 0.0) -> tuple[int, float]:
    """Cycles and (slightly adjusted) period that fill ``duration`` s (at least one cycle).

    The period stays within [0.7, 1.5] x ``period`` and above ``min_period`` (the speed limit), so a
    very short duration still gives one recognisable cycle.
    """
    period = max(period, min_period)
    if duration <= 0:
        return 1, period
    n = max(1, round(duration / period))
    if min_period > 0:  # never so many cycles that the speed limit stretches them past ``duration``
        fit = duration / min_period  # inf for a subnormal min_period (a sweep of ~1e-313 rad): no bound
        if math.isfinite(fit):
            n = max(1, min(n, int(fit + 1e-9)))
    p = min(max(duration / n, 0.7 * period, min_period), 1.5 * period)
    return n, p


def _finish(track: Track, persistent: bool, fn: Callable[[np.ndarray], np.ndarray], period: float,
            cycles: int, end: np.ndarray, end_time: float = 0.0) -> Motion:
    """Rhythmic tail: loop one cycle when persistent, else ``cycles`` cycles then move to ``end``."""
    if persistent:
        track.cycle(fn, period, 0)
        track.mark_loop()
        track.cycle(fn, period, 1)
        return track.build()
    track.cycle(fn, period, cycles)
    track.move(end, end_time)
    return track.build()


# --- body: postures -------------------------------------------------------------------------


def _body(hips: dict[int, float] | None = None, knees: dict[int, float] | None = None,
          base: np.ndarray | None = None) -> np.ndarray:
    """Body-channel pose from the stand pose (or ``base``) with some legs' hips/knees set (degrees)."""
    q = stand_body() if base is None else base.copy()
    for leg, v in (hips or {}).items():
        q[HIP_COLS[leg - 1]] = rad(v)
    for leg, v in (knees or {}).items():
        q[KNEE_COLS[leg - 1]] = rad(v)
    return q


def _all(v: float) -> dict[int, float]:
    return {1: v, 2: v, 3: v, 4: v}


STAND_POSTURES: dict[str, np.ndarray] = {
    "normal": stand_body(),
    "forward": _body(knees={1: 40, 2: 40, 3: 5, 4: 5}),
    "backward": _body(knees={1: 5, 2: 5, 3: 40, 4: 40}),
}
SIT_STYLES: dict[str, np.ndarray] = {
    "normal": np.array(load_poses()["sit"])[list(BODY)],
    "dog": _body(hips={1: 20, 2: 20, 3: -20, 4: -20}, knees={1: 0, 2: 0, 3: 90, 4: 90}),
}


def _posture(channel: str, start: np.ndarray, pose: np.ndarray, speed: float, duration: float,
             persistent: bool, min_time: float = 0.3) -> Motion:
    """Move to ``pose``; finite: the whole motion lasts about ``duration`` s; persistent: hold."""
    track = Track(_servos(channel), check_start(start))
    track.move(pose, min(min_time, duration) if track.min_time(pose) > 0 else 0.0, speed)
    if persistent:
        return track.build(hold_end=True)
    track.hold(max(duration - track.now, DT))
    return track.build()


def stand(start: np.ndarray, *, persistent: bool = False, posture: str = "normal",
          duration: float = 1.0) -> Motion:
    """Stand up; "forward"/"backward" tilt the body that way."""
    pose = check_choice(posture, STAND_POSTURES, "posture")
    return _posture("body", start, pose, BODY_SPEED, _seconds(duration), persistent)


def sit(start: np.ndarray, *, persistent: bool = False, style: str = "normal", duration: float = 1.0) -> Motion:
    """Sit down; "dog" squats on the hind legs."""
    pose = check_choice(style, SIT_STYLES, "style")
    return _posture("body", start, pose, BODY_SPEED, _seconds(duration), persistent)


LEAN: dict[str, np.ndarray] = {
    "forward": _body(knees={1: 45, 2: 45, 3: 0, 4: 0}),
    "backward": _body(knees={1: 0, 2: 0, 3: 45, 4: 45}),
    "left": _body(knees={1: 0, 2: 45, 3: 45, 4: 0}),
    "right": _body(knees={1: 45, 2: 0, 3: 0, 4: 45}),
}


def body_lean(start: np.ndarray, *, persistent: bool = False, direction: str = "left",
              duration: float = 1.0) -> Motion:
    """Lean towards ``direction``, hold, and come back (persistent: stay leaning)."""
    pose = check_choice(direction, LEAN, "direction")
    duration = _seconds(duration)
    track = Track(BODY, check_start(start)).move(stand_body(), speed=BODY_SPEED)
    track.move(pose, 0.4, BODY_SPEED)
    if persistent:
        return track.build(hold_end=True)
    track.hold(max(0.0, duration - 0.8))
    track.move(stand_body(), 0.4, BODY_SPEED)
    return track.build()


# --- body: rhythmic whole-body skills ---------------------------------------------------------

#: Rolls in one wet-dog shake (the gesture ``shake_like_dog`` plays without a duration).
DOG_SHAKE_ROLLS = 3


def _wave_fn(base: np.ndarray, offsets: np.ndarray, shape: Callable[[np.ndarray], np.ndarray]
             ) -> Callable[[np.ndarray], np.ndarray]:
    """Cycle ``base + shape(phase) * offsets``."""
    return lambda ph: base[None, :] + shape(ph)[:, None] * offsets[None, :]


def _bump(ph: np.ndarray) -> np.ndarray:
    """0 -> 1 -> 0 over one cycle, smooth at both ends."""
    return (1.0 - np.cos(2.0 * np.pi * ph)) / 2.0


def _sine(ph: np.ndarray) -> np.ndarray:
    return np.sin(2.0 * np.pi * ph)


def push_up(start: np.ndarray, *, persistent: bool = False, duration: float = 0.0, times: int = 1) -> Motion:
    """Push-ups: ``times`` repetitions, or as many as fit in ``duration`` s when it is > 0."""
    duration, times = _seconds(duration), check_count(times)
    base = stand_body()
    fn = _wave_fn(base, _body(knees=_all(60.0)) - base, _bump)
    period = 1.2
    n = times if duration <= 0 else _rhythm(duration, period)[0]
    if duration > 0:
        period = _rhythm(duration, period)[1]
    track = Track(BODY, check_start(start)).move(base, speed=BODY_SPEED)
    return _finish(track, persistent, fn, period, n, base)


def wriggle(start: np.ndarray, *, persistent: bool = False, duration: float = 0.0) -> Motion:
    """Wriggle: the body twists (yaw) and rolls side to side."""
    duration = _seconds(duration)
    base = stand_body()
    twist = np.zeros(8)
    twist[HIP_COLS] = rad(12.0) * gaits.TURN_LEFT
    roll = np.zeros(8)
    roll[KNEE_COLS] = rad(12.0) * np.array([-1.0, 1.0, 1.0, -1.0])

    fn = _wave_fn(base, twist + roll, _sine)

    period = 0.8
    n, period = _rhythm(duration, period)
    track = Track(BODY, check_start(start)).move(base, speed=BODY_SPEED)
    return _finish(track, persistent, fn, period, n, base)


def shake_like_dog(start: np.ndarray, *, persistent: bool = False, duration: float = 0.0) -> Motion:
    """Shake the body like a wet dog: a fast roll from side to side."""
    duration = _seconds(duration)
    base = _body(knees=_all(20.0))
    roll = np.zeros(8)
    roll[KNEE_COLS] = rad(14.0) * np.array([1.0, -1.0, -1.0, 1.0])
    twist = np.zeros(8)
    twist[HIP_COLS] = rad(6.0) * gaits.TURN_LEFT
    fn = lambda ph: base + _sine(ph)[:, None] * (roll + twist)  # noqa: E731
    n, period = _rhythm(duration, 0.3, min_period=0.28)
    if duration <= 0:
        n = DOG_SHAKE_ROLLS  # one shake of a wet dog is a short burst of rolls
    track = Track(BODY, check_start(start)).move(base, speed=BODY_SPEED)
    return _finish(track, persistent, fn, period, n, stand_body())


def shake_ass(start: np.ndarray, *, persistent: bool = False, speed: float = 50, times: int = 1,
              amplitude: float = 50) -> Motion:
    """Wiggle the rear of the body side to side ``times`` times."""
    s, a, times = _unit(speed, "speed"), _unit(amplitude, "amplitude"), check_count(times)
    base = _body(knees={1: 10, 2: 10, 3: 25, 4: 25})
    amp = rad(8.0 + 17.0 * a)
    off = np.zeros(8)
    off[HIP_COLS[2]], off[HIP_COLS[3]] = amp, -amp  # back feet sideways: the rear swings
    period = max(0.9 - 0.5 * s, 2 * math.pi * amp / (0.8 * LEG_VMAX))
    track = Track(BODY, check_start(start)).move(base, speed=BODY_SPEED)
    return _finish(track, persistent, _wave_fn(base, off, _sine), period, times, stand_body())


def chest_expansion_exercise(start: np.ndarray, *, persistent: bool = False, times: int = 1) -> Motion:
    """Open and close both front legs like a chest-expansion exercise (weight shifted back)."""
    times = check_count(times)
    base = _body(knees={1: 30, 2: 30, 3: 20, 4: 20})
    off = np.zeros(8)
    off[HIP_COLS[0]] = off[HIP_COLS[1]] = rad(-30.0)  # front feet sweep back-outward: chest opens
    off[KNEE_COLS[0]] = off[KNEE_COLS[1]] = rad(20.0)
    track = Track(BODY, check_start(start)).move(base, speed=BODY_SPEED)
    return _finish(track, persistent, _wave_fn(base, off, _bump), 1.4, times, stand_body())


def fly_rub_hands(start: np.ndarray, *, persistent: bool = False, times: int = 1) -> Motion:
    """Rub the two front legs together like a fly: front feet slide against each other in turn."""
    times = check_count(times)
    base = _body(hips={1: 15, 2: 15}, knees={1: 35, 2: 35, 3: 25, 4: 25})
    off = np.zeros(8)
    off[HIP_COLS[0]], off[HIP_COLS[1]] = rad(12.0), rad(-12.0)
    off[KNEE_COLS[0]], off[KNEE_COLS[1]] = rad(10.0), rad(-10.0)
    track = Track(BODY, check_start(start)).move(base, speed=BODY_SPEED)
    return _finish(track, persistent, _wave_fn(base, off, _sine), 0.5, times, stand_body())


# --- body: one-leg skills (weight shifted onto the other three) --------------------------------

#: Hip offsets (degrees) that move the diagonal support line towards the corner of the lifted leg.
SHIFT: dict[int, dict[int, float]] = {
    1: {2: 40.0, 4: 40.0},
    2: {1: 40.0, 3: 40.0},
    3: {2: -40.0, 4: -40.0},
    4: {1: -40.0, 3: -40.0},
}


def _leg(leg: int) -> int:
    if isinstance(leg, bool) or not isinstance(leg, (int, float)) or leg not in (1, 2, 3, 4):
        raise ValueError(f"leg must be 1 (front-right), 2 (front-left), 3 (back-left) or 4 (back-right), got {leg!r}")
    return int(leg)


def _shifted(leg: int) -> np.ndarray:
    return _body(hips=SHIFT[leg])


def _raise(track: Track, leg: int, knee: float = 80.0, hip: float = 0.0) -> np.ndarray:
    """Shift the weight off ``leg`` and lift it; returns the lifted pose."""
    shifted = _shifted(leg)
    track.move(stand_body(), speed=BODY_SPEED).move(shifted, 0.5, BODY_SPEED)
    lifted = _body(hips={leg: hip}, knees={leg: knee}, base=shifted)
    track.move(lifted, 0.35)
    return lifted


def _lower(track: Track, leg: int) -> None:
    track.move(_shifted(leg), 0.35).move(stand_body(), 0.5, BODY_SPEED)


def wave(start: np.ndarray, *, persistent: bool = False, times: int = 1, speed: float = 50,
         amplitude: float = 50) -> Motion:
    """Wave the front-right leg like a hand ``times`` times."""
    times, s, a = check_count(times), _unit(speed, "speed"), _unit(amplitude, "amplitude")
    track = Track(BODY, check_start(start))
    lifted = _raise(track, 1, knee=85.0)
    amp = rad(10.0 + 25.0 * a)
    off = np.zeros(8)
    off[HIP_COLS[0]] = amp
    period = max(0.9 - 0.5 * s, 2 * math.pi * amp / (0.8 * LEG_VMAX))
    fn = _wave_fn(lifted, off, _sine)
    if persistent:
        return _finish(track, True, fn, period, 0, lifted)
    track.cycle(fn, period, times)
    _lower(track, 1)
    return track.build()


def single_leg_knock(start: np.ndarray, *, persistent: bool = False, leg: int = 1, times: int = 1,
                     speed: float = 50) -> Motion:
    """Tap the ground with one leg (1 front-right, 2 front-left, 3 back-left, 4 back-right)."""
    leg, times, s = _leg(leg), check_count(times), _unit(speed, "speed")
    track = Track(BODY, check_start(start))
    lifted = _raise(track, leg, knee=70.0, hip=15.0 if leg in (1, 2) else -15.0)
    off = np.zeros(8)
    off[KNEE_COLS[leg - 1]] = rad(8.0) - lifted[KNEE_COLS[leg - 1]]  # down to the floor and back
    fn = _wave_fn(lifted, off, _bump)
    period = max(0.8 - 0.45 * s, math.pi * abs(off[KNEE_COLS[leg - 1]]) / (0.8 * LEG_VMAX))
    if persistent:
        return _finish(track, True, fn, period, 0, lifted)
    track.cycle(fn, period, times)
    _lower(track, leg)
    return track.build()


def _pull_cycle(track: Track, leg: int, period: float, push: bool = False) -> None:
    """Reach forward, grab the floor, pull back, lift (one rope pull with ``leg``; ``push``: the reverse)."""
    lifted = lambda hip, knee: _body(hips={leg: hip}, knees={leg: knee}, base=_shifted(leg))  # noqa: E731
    cycle = ((35.0, 75.0), (35.0, 15.0), (-15.0, 15.0), (-15.0, 75.0))
    if push:
        cycle = ((-15.0, 75.0), (-15.0, 15.0), (35.0, 15.0), (35.0, 75.0))
    for hip, knee in cycle:
        track.move(lifted(hip, knee), period / 4)


def arm_pull(start: np.ndarray, *, persistent: bool = False, direction: str = "both", speed: float = 50,
             times: int = 1) -> Motion:
    """Pull the front legs towards the body like pulling a rope ("both"/"forward": hand over hand;
    "backward": push both away from the body)."""
    legs = check_choice(direction, {"left": (2,), "right": (1,), "both": (1, 2), "forward": (1, 2),
                                    "backward": (1, 2)}, "direction")
    push = direction == "backward"
    times, s = check_count(times), _unit(speed, "speed")
    period = 1.6 - 0.8 * s
    track = Track(BODY, check_start(start))
    if persistent:
        legs = legs[:1]
    for i, leg in enumerate(legs if persistent else [legs[k % len(legs)] for k in range(times * len(legs))]):
        _raise(track, leg, knee=75.0, hip=-15.0)
        if persistent:
            track.mark_loop()
            _pull_cycle(track, leg, period, push)
            return track.build()
        _pull_cycle(track, leg, period, push)
        _lower(track, leg)
    return track.build()


def arm_knock(start: np.ndarray, *, persistent: bool = False, speed: float = 50, times: int = 1) -> Motion:
    """Knock the ground with both front legs in turn (``times`` rounds)."""
    times, s = check_count(times), _unit(speed, "speed")
    period = 0.8 - 0.45 * s
    track = Track(BODY, check_start(start))

    def knock(leg: int) -> None:
        lifted = _raise(track, leg, knee=70.0, hip=15.0)
        off = np.zeros(8)
        off[KNEE_COLS[leg - 1]] = rad(8.0) - lifted[KNEE_COLS[leg - 1]]
        track.cycle(_wave_fn(lifted, off, _bump), max(period, 0.35), 1)
        _lower(track, leg)

    if persistent:
        track.move(stand_body(), speed=BODY_SPEED).mark_loop()
        knock(1)
        knock(2)
        return track.build()
    for _ in range(times):
        knock(1)
        knock(2)
    return track.build()


# --- head -----------------------------------------------------------------------------------


def head_pose(start: np.ndarray, *, persistent: bool = False, yaw: float = 0.0, pitch: float = 0.0) -> Motion:
    """Turn the head to (yaw, pitch) degrees; yaw < 0 looks right. Persistent: hold there."""
    check_finite(yaw=yaw, pitch=pitch)
    track = Track(HEAD, check_start(start))
    target = np.clip([rad(yaw), rad(pitch)], track.lo, track.hi)
    track.move(target, 0.25 if track.min_time(target) > 0 else 0.0, HEAD_SPEED)
    return track.build(hold_end=persistent)


def head_act(start: np.ndarray, *, persistent: bool = False, action: str = "nod", duration: float = 0.0) -> Motion:
    """Nod (pitch) or shake (yaw) the head around where it points: once, or for ``duration`` s when > 0."""
    col, amp, period = check_choice(action, {"nod": (1, rad(15.0), 0.6), "shake": (0, rad(25.0), 0.7)}, "action")
    duration = _seconds(duration)
    start = check_start(start)
    track = Track(HEAD, start)
    home = track.q
    base = home.copy()
    base[col] = np.clip(base[col], track.lo[col] + amp, track.hi[col] - amp)
    off = np.zeros(2)
    off[col] = -amp if action == "nod" else amp
    n, period = _rhythm(duration, period, min_period=2 * math.pi * amp / (0.8 * track.vmax[col]))
    return _finish(track, persistent, _wave_fn(base, off, _sine), period, n, home)


# --- ears -----------------------------------------------------------------------------------

#: Ear postures (left, right) in degrees; + flops an ear outward, 0 is upright.
EAR_STATES: dict[str, tuple[float, float]] = {
    "up": (0.0, 0.0),
    "alert": (-15.0, -15.0),
    "inquisitive": (-10.0, 45.0),
    "relaxed": (30.0, 30.0),
    "down": (65.0, 65.0),
    "droop": (80.0, 80.0),
    "back": (-30.0, -30.0),
    # flattened back as far as the ears go (-30 deg), as if facing an opponent
    "flattened": (-30.0, -30.0), "flat": (-30.0, -30.0), "flattened_back": (-30.0, -30.0),
    "pinned_back": (-30.0, -30.0), "opponent": (-30.0, -30.0), "aggressive": (-30.0, -30.0),
    "angry": (-28.0, -28.0), "scared": (-25.0, -25.0), "fear": (-25.0, -25.0),
    # perked up and forward
    "perked": (-20.0, -20.0), "perked_up": (-20.0, -20.0), "perk": (-20.0, -20.0), "raised": (-20.0, -20.0),
    "attentive": (-15.0, -15.0), "listening": (-20.0, 10.0), "forward": (-5.0, -5.0),
    # lowered, turned out
    "shy": (50.0, 35.0), "timid": (50.0, 50.0), "curious": (-10.0, 45.0), "tilted": (0.0, 40.0),
    "sad": (75.0, 75.0), "droopy": (80.0, 80.0), "sleepy": (70.0, 70.0), "tired": (70.0, 70.0),
    "happy": (10.0, 10.0), "neutral": (0.0, 0.0), "normal": (0.0, 0.0),
}


def ear_state(start: np.ndarray, *, persistent: bool = False, state: str = "up", duration: float = 1.0) -> Motion:
    """Hold the ears in a posture for ``duration`` s (persistent: until released)."""
    pose = np.radians(check_choice(state, EAR_STATES, "ear state"))
    return _posture("ears", start, pose, EAR_SPEED, _seconds(duration), persistent, min_time=0.2)


def shake_ear(start: np.ndarray, *, persistent: bool = False, duration: float = 0.0) -> Motion:
    """Flap both ears once (or for ``duration`` s when > 0), then return them where they were."""
    duration = _seconds(duration)
    track = Track(EARS, check_start(start))
    home = track.q
    amp = rad(45.0)
    base = np.clip(home, track.lo, track.hi - amp)
    fn = _wave_fn(base, np.array([amp, amp]), _bump)
    n, period = _rhythm(duration, 0.45, min_period=math.pi * amp / (0.8 * float(track.vmax.min())))
    return _finish(track, persistent, fn, period, n, home)


def ear_swing(start: np.ndarray, *, persistent: bool = False, side: str = "left", start_angle: float = -30.0,
              end_angle: float = 30.0, speed: float = 50, duration: float = 0.0) -> Motion:
    """Swing one ear between two angles (degrees, clipped to the ear's range) once, or for ``duration`` s."""
    col = check_choice(side, {"left": 0, "right": 1}, "side")
    check_finite(start_angle=start_angle, end_angle=end_angle)
    s, duration = _unit(speed, "speed"), _seconds(duration)
    track = Track(EARS, check_start(start))
    home = track.q
    a0, a1 = np.clip([rad(start_angle), rad(end_angle)], track.lo[col], track.hi[col])
    base = home.copy()
    base[col] = a0
    off = np.zeros(2)
    off[col] = a1 - a0
    n, period = _rhythm(duration, 1.2 - 0.9 * s, min_period=math.pi * abs(a1 - a0) / (0.8 * track.vmax[col]))
    track.move(base, 0.0, EAR_SPEED)
    return _finish(track, persistent, _wave_fn(base, off, _bump), period, n, home)


# --- registry -------------------------------------------------------------------------------

BEHAVIOURS: dict[str, Callable[..., Motion]] = {
    # body
    "stand": stand, "sit": sit, "push_up": push_up, "wave": wave,
    "chest_expansion_exercise": chest_expansion_exercise, "fly_rub_hands": fly_rub_hands,
    "body_lean": body_lean, "run_distance": gaits.run_distance, "rotate": gaits.rotate,
    "move_strides": gaits.move_strides, "creep": gaits.creep, "wriggle": wriggle,
    "single_leg_knock": single_leg_knock, "shake_ass": shake_ass, "shake_like_dog": shake_like_dog,
    "arm_pull": arm_pull, "arm_knock": arm_knock,
    # head
    "head_act": head_act, "head_pose": head_pose,
    # ears
    "shake_ear": shake_ear, "ear_state": ear_state, "ear_swing": ear_swing,
}
_HEAD = {"head_act", "head_pose"}
_EARS = {"shake_ear", "ear_state", "ear_swing"}


def channel_of(behaviour: str) -> str:
    """The channel (body, head or ears) a motion behaviour drives."""
    if behaviour not in BEHAVIOURS:
        raise ValueError(f"unknown motion behaviour {behaviour!r}; known: {', '.join(sorted(BEHAVIOURS))}")
    return "head" if behaviour in _HEAD else "ears" if behaviour in _EARS else "body"

