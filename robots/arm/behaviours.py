"""The arm's behaviours: one trajectory generator per gesture and manipulation skill.

Every generator has the signature ``gen(start, *, persistent=False, **params) -> Motion``
(:data:`robots.description.Behaviour`): ``start`` holds the current joint targets of all six servos
(radians), ``params`` are the stub parameters of ``robots/arm/interface.py`` (seconds, counts,
names). Each motion starts exactly at ``start``, stays inside the joint limits and under the speed
limits (:class:`robots.motion.JointLimits` of the servo table; :meth:`robots.motion.Track.build` checks
the speed of every sample), and drives

- the ``arm`` channel's five servos: ``point_at``, ``wave``, ``nod``, ``shake``; ``pick`` and
  ``place`` drive the gripper too (they open and close it as part of the skill);
- the ``gripper`` channel's servo: ``grip``, ``release``, ``snap``.

Finite form: one call = one gesture. A rhythmic gesture (wave, nod, shake, snap) without
``times``/``duration`` plays once at its natural tempo; ``times`` repeats it, ``duration`` > 0
repeats it to fill about that many seconds; then the servos return to where they began. Skills end
where they lead (pick: holding the object above its place; place: the hand above the released
object). Persistent form (the element used as a parent): rhythmic gestures loop one seamless cycle
until released; the others hold their end pose.

Where objects are: ``pick`` and ``place`` plan from the positions the robot's default scene declares
(``robot.toml`` ``[scenes.table]``), and ``place(on=...)`` also accepts the named spots of
``places.toml``. The host does not see live object poses (the board reports none), so an object that
an earlier call moved is still sought where the scene put it; nothing here tracks it.

Grasp plan (cube of half size ``h``): the hand points straight down with the jaws square to the
cube (:meth:`robots.arm.kinematics.ArmGeometry.square_roll`), opens to :data:`OPEN_DEG` above the
cube, descends in a straight line until the grasp point is ``h + GRASP_ABOVE_CENTRE_M`` above the
table, closes (the command goes to 0 deg; a 25 mm cube stops the jaw at about 25 deg and the
servo squeezes at its torque limit), and lifts straight up. ``place`` carries the object above
the target, lowers it until its bottom is :data:`DROP_M` above the target's top, opens and rises.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from robots.arm.kinematics import DOWN, ArmGeometry
from robots.description import Behaviour, Robot, SceneObjectSpec
from robots.motion import DT, JointLimits, Motion, Track, check_count, check_finite, check_start, min_jerk
from robots.registry import load_robot

__all__ = ["BEHAVIOURS", "ROBOT", "geometry", "places", "target_point"]

rad = math.radians
_HERE = Path(__file__).resolve().parent
#: this package's robot (the same value ``load_robot("arm")`` returns)
ROBOT: Robot = load_robot(str(_HERE))
LIMITS = JointLimits.of_robot(ROBOT)
_T = ROBOT.servos
PAN, LIFT, ELBOW, WFLEX, WROLL, GRIP = (_T.by_name(n).index for n in (
    "shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper"))
ARM: tuple[int, ...] = ROBOT.channels["arm"].servos
HAND: tuple[int, ...] = ROBOT.channels["gripper"].servos
BOTH: tuple[int, ...] = tuple(sorted(ARM + HAND))

#: travelling speed of the arm's joints (rad/s), well under the servos' 300 deg/s
TRAVEL_SPEED = rad(120.0)
#: the gripper opened for a grasp, released, and commanded closed (degrees)
OPEN_DEG, RELEASE_DEG, CLOSED_DEG = 45.0, 45.0, 0.0
#: the grasp point sits this far above the object's centre (the jaw tips stay clear of the table)
GRASP_ABOVE_CENTRE_M = 0.0035
#: height of the approach above the grasp point (pick) and above the release point (place), m
PICK_HOVER_M, PLACE_HOVER_M = 0.06, 0.045
#: a placed object is let go with its bottom this far above the surface it goes on (m)
DROP_M = 0.003
#: point_at hovers the grasp point this far above the target's top (m)
POINT_HOVER_M = 0.06


#: the arm's link lengths and base, read from its MJCF once at import (a first call must not wait for it)
GEOMETRY = ArmGeometry.from_mjcf(ROBOT.mjcf)


def geometry() -> ArmGeometry:
    """The arm's link lengths and base, read from its MJCF (:class:`robots.arm.kinematics.ArmGeometry`)."""
    return GEOMETRY


def _read_places() -> dict[str, tuple[float, float]]:
    with open(ROBOT.data["places"], "rb") as f:
        doc = tomllib.load(f)
    return {str(k): (float(v[0]), float(v[1])) for k, v in doc["places"].items()}


PLACES = _read_places()


def places() -> Mapping[str, tuple[float, float]]:
    """Named spots on the table top (``places.toml``): name -> (x, y) in metres."""
    return PLACES


def _objects() -> dict[str, SceneObjectSpec]:
    """The movable objects of the default scene by name."""
    return {o.name: o for o in ROBOT.scene().objects if o.free}


def _top(o: SceneObjectSpec) -> float:
    """Height of the top face of ``o`` where the scene puts it (m)."""
    half = o.size[2] if o.shape == "box" else o.size[1] if o.shape == "cylinder" else o.size[0]
    return o.pos[2] + half


def _half_height(o: SceneObjectSpec) -> float:
    return o.size[2] if o.shape == "box" else o.size[1] if o.shape == "cylinder" else o.size[0]


def target_point(name: str) -> tuple[float, float, float, float]:
    """(x, y, top z, yaw rad) of a scene object or a named spot (a spot's top is the table, z = 0);
    ValueError naming the valid targets otherwise."""
    objs = _objects()
    if name in objs:
        o = objs[name]
        return o.pos[0], o.pos[1], _top(o), rad(o.euler_deg[2])
    spots = places()
    if name in spots:
        x, y = spots[name]
        return x, y, 0.0, 0.0
    raise ValueError(f"no object or place {name!r}; objects: {', '.join(objs)}; places: {', '.join(spots)}")


# --- building blocks -----------------------------------------------------------------------------


#: a point in the world (m): x, y, z
Point = Sequence[float] | np.ndarray


def _down_pose(point: Point, yaw: float = 0.0) -> np.ndarray:
    """The five arm joints (rad) that put the grasp point at ``point`` with the hand straight down
    and the jaws square to a box at ``yaw``."""
    g = geometry()
    pan = math.atan2(point[1] - g.base[1], point[0] - g.base[0])
    return g.solve(point, DOWN, g.square_roll(pan, yaw))


def _full(arm: np.ndarray, grip: float) -> np.ndarray:
    """A six-servo target (servo order) from the arm's five joints and the gripper angle."""
    q = np.zeros(LIMITS.n)
    q[list(ARM)] = arm
    q[GRIP] = grip
    return q


def _line(track: Track, a: Point, b: Point, duration: float, yaw: float,
          grip: float) -> None:
    """A straight line of the grasp point from ``a`` to ``b`` (hand down) in ``duration`` s with a
    minimum-jerk profile along it, the gripper held at ``grip`` rad (track over all six servos)."""
    pa, pb = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    n = max(2, math.ceil(duration / DT))
    rows = [_full(_down_pose(pa + (pb - pa) * s, yaw), grip) for s in min_jerk(np.arange(1, n + 1) / n)]
    track.samples(duration / n, np.array(rows))


def _travel(track: Track, target: np.ndarray, min_duration: float = 0.6) -> None:
    """Joint-space minimum-jerk move of the track's servos to ``target`` (six-servo vector) at travel speed."""
    goal = np.asarray(target, dtype=float)[list(track.servos)]
    track.move(goal, min_duration, speed=TRAVEL_SPEED)


def _cycles(times: int, duration: float, period: float) -> tuple[int, float]:
    """How many cycles a rhythmic gesture plays and at what period (s): ``times`` at ``period``, or
    as many as fill ``duration`` s, the period stretched or shrunk (not below 0.8 x, where the
    gestures' speeds stay under the servos' limits) so they fill it."""
    check_finite(duration=duration)
    if duration < 0:
        raise ValueError(f"duration must be >= 0 s, got {duration}")
    n = check_count(times)
    if duration <= 0:
        return n, period
    n = max(1, round(duration / period))
    return n, max(duration / n, 0.8 * period)


def _rhythm(start: np.ndarray, servos: tuple[int, ...], persistent: bool, times: int, duration: float,
            period: float, fn: Callable[[np.ndarray], np.ndarray], setup: np.ndarray | None = None) -> Motion:
    """A rhythmic gesture: (move to ``setup``,) ``fn(phase)`` (k, len(servos)) absolute targets per
    cycle, then back to ``start``; persistent: loops one cycle. ``fn(0)`` must equal where the cycle
    starts (the setup pose, or the start)."""
    q0 = check_start(start, LIMITS)
    n, period = _cycles(times, duration, period)
    track = Track(servos, q0, LIMITS)
    if setup is not None:
        _travel(track, setup, 0.5)
    if persistent:
        track.mark_loop()
        track.cycle(fn, period, 1)
        return track.build()
    track.cycle(fn, period, n)
    back = q0[list(servos)]
    if float(np.max(np.abs(track.q - back))) > 1e-9:
        track.move(back, 0.4, speed=TRAVEL_SPEED)
    return track.build()


def _hold(m: Motion) -> Motion:
    """The persistent form of a move: its last sample held (a loop of one sample)."""
    return Motion(m.servos, m.t, m.q, float(m.t[-1]))


# --- arm: gestures ---------------------------------------------------------------------------------


#: the raised-hand pose waves start from (degrees: lift, elbow, wrist_flex; pan 0, roll 0)
WAVE_POSE = (-10.0, -45.0, -35.0)
WAVE_PAN_DEG, WAVE_WRIST_DEG, WAVE_PERIOD_S = 18.0, 12.0, 1.1


def wave(start: np.ndarray, *, persistent: bool = False, times: int = 1, duration: float = 0.0) -> Motion:
    """Raise the hand and wave it side to side (pan and wrist swing together), ``times`` waves or
    waves for ``duration`` s, then lower it back where it was."""
    q0 = check_start(start, LIMITS)
    up = q0.copy()
    up[[PAN, LIFT, ELBOW, WFLEX, WROLL]] = [0.0, *(rad(v) for v in WAVE_POSE), 0.0]
    base = up[list(ARM)]
    amp = np.zeros(len(ARM))
    amp[ARM.index(PAN)], amp[ARM.index(WFLEX)] = rad(WAVE_PAN_DEG), rad(WAVE_WRIST_DEG)

    def fn(ph: np.ndarray) -> np.ndarray:
        return base + np.sin(2 * math.pi * ph)[:, None] * amp

    return _rhythm(q0, ARM, persistent, times, duration, WAVE_PERIOD_S, fn, setup=up)


NOD_DEG, NOD_PERIOD_S = 22.0, 0.7
#: a nod dips the hand (wrist_flex +) only if the grasp point stays this high above the table (m)
NOD_CLEARANCE_M = 0.05


def nod(start: np.ndarray, *, persistent: bool = False, times: int = 1, duration: float = 0.0) -> Motion:
    """Nod with the wrist: the hand dips :data:`NOD_DEG` and comes back, from wherever the arm is
    (it tips up instead when a dip would bring the gripper near the table)."""
    q0 = check_start(start, LIMITS)
    g = geometry()
    dip = q0.copy()
    dip[WFLEX] = min(q0[WFLEX] + rad(NOD_DEG), LIMITS.hi[WFLEX])
    sign = 1.0 if (g.forward(dip)[0][2] >= NOD_CLEARANCE_M and dip[WFLEX] - q0[WFLEX] > rad(NOD_DEG) / 2) else -1.0
    base = q0[list(ARM)]
    amp = np.zeros(len(ARM))
    amp[ARM.index(WFLEX)] = sign * rad(NOD_DEG)

    def fn(ph: np.ndarray) -> np.ndarray:
        return base + (0.5 - 0.5 * np.cos(2 * math.pi * ph))[:, None] * amp

    return _rhythm(q0, ARM, persistent, times, duration, NOD_PERIOD_S, fn)


SHAKE_DEG, SHAKE_PERIOD_S = 25.0, 0.8


def shake(start: np.ndarray, *, persistent: bool = False, times: int = 1, duration: float = 0.0) -> Motion:
    """Shake the hand "no": the wrist rolls :data:`SHAKE_DEG` one way and the other and back."""
    q0 = check_start(start, LIMITS)
    base = q0[list(ARM)]
    room = min(LIMITS.hi[WROLL] - q0[WROLL], q0[WROLL] - LIMITS.lo[WROLL])
    amp = np.zeros(len(ARM))
    amp[ARM.index(WROLL)] = min(rad(SHAKE_DEG), max(room, 0.0))

    def fn(ph: np.ndarray) -> np.ndarray:
        return base + np.sin(2 * math.pi * ph)[:, None] * amp

    return _rhythm(q0, ARM, persistent, times, duration, SHAKE_PERIOD_S, fn)


def point_at(start: np.ndarray, *, persistent: bool = False, target: str = "red_cube") -> Motion:
    """Point the gripper straight down at a scene object or a named place from
    :data:`POINT_HOVER_M` above its top (the wrist camera then looks at it)."""
    q0 = check_start(start, LIMITS)
    x, y, top, yaw = target_point(target)
    goal = q0.copy()
    goal[list(ARM)] = _down_pose((x, y, top + POINT_HOVER_M), yaw)
    track = Track(ARM, q0, LIMITS)
    _travel(track, goal, 0.8)
    m = track.build()
    return _hold(m) if persistent else m


# --- arm: manipulation -----------------------------------------------------------------------------


def _grasp_point(o: SceneObjectSpec) -> tuple[float, float, float]:
    """Where the grasp point goes to hold ``o``: above its centre by :data:`GRASP_ABOVE_CENTRE_M`."""
    return o.pos[0], o.pos[1], o.pos[2] + GRASP_ABOVE_CENTRE_M


def _object(name: str) -> SceneObjectSpec:
    objs = _objects()
    try:
        return objs[name]
    except KeyError:
        raise ValueError(f"no object {name!r} to handle; objects: {', '.join(objs)}") from None


def pick(start: np.ndarray, *, persistent: bool = False, object: str = "red_cube") -> Motion:
    """Pick ``object`` up: open above it, descend, close on it, lift it :data:`PICK_HOVER_M`."""
    q0 = check_start(start, LIMITS)
    o = _object(object)
    yaw = rad(o.euler_deg[2])
    grasp = np.array(_grasp_point(o))
    above = grasp + (0.0, 0.0, PICK_HOVER_M)
    track = Track(BOTH, q0, LIMITS)
    _travel(track, _full(_down_pose(above, yaw), rad(OPEN_DEG)), 0.8)
    _line(track, above, grasp, 0.8, yaw, rad(OPEN_DEG))
    track.move(_full(_down_pose(grasp, yaw), rad(CLOSED_DEG)), 0.5)
    track.hold(0.25)
    _line(track, grasp, above, 0.8, yaw, rad(CLOSED_DEG))
    m = track.build()
    return _hold(m) if persistent else m


def place(start: np.ndarray, *, persistent: bool = False, object: str = "red_cube", on: str = "front") -> Motion:
    """Put the held ``object`` down on another object or a named place: carry it above the target,
    lower it until its bottom is :data:`DROP_M` above the target's top, open, rise."""
    q0 = check_start(start, LIMITS)
    o = _object(object)
    if on == object:
        raise ValueError(f"cannot place {object} on itself")
    x, y, top, yaw = target_point(on)
    release = np.array([x, y, top + DROP_M + _half_height(o) + GRASP_ABOVE_CENTRE_M])
    above = release + (0.0, 0.0, PLACE_HOVER_M)
    grip = float(q0[GRIP])
    track = Track(BOTH, q0, LIMITS)
    _travel(track, _full(_down_pose(above, yaw), grip), 0.8)
    _line(track, above, release, 0.8, yaw, grip)
    track.move(_full(_down_pose(release, yaw), rad(RELEASE_DEG)), 0.4)
    track.hold(0.2)
    _line(track, release, above, 0.6, yaw, rad(RELEASE_DEG))
    m = track.build()
    return _hold(m) if persistent else m


# --- gripper ---------------------------------------------------------------------------------------


def _jaw(start: np.ndarray, deg: float, persistent: bool) -> Motion:
    q0 = check_start(start, LIMITS)
    track = Track(HAND, q0, LIMITS)
    track.move([rad(deg)], 0.4)
    m = track.build()
    return _hold(m) if persistent else m


def grip(start: np.ndarray, *, persistent: bool = False) -> Motion:
    """Close the gripper (the command goes fully closed; an object between the jaws stops them and
    the servo squeezes it at its torque limit)."""
    return _jaw(start, CLOSED_DEG, persistent)


def release(start: np.ndarray, *, persistent: bool = False) -> Motion:
    """Open the gripper to :data:`RELEASE_DEG` (lets go of what it holds)."""
    return _jaw(start, RELEASE_DEG, persistent)


SNAP_DEG, SNAP_PERIOD_S = 40.0, 0.6


def snap(start: np.ndarray, *, persistent: bool = False, times: int = 1, duration: float = 0.0) -> Motion:
    """Snap the jaws: open :data:`SNAP_DEG` wider and close back to where they were."""
    q0 = check_start(start, LIMITS)
    base = q0[list(HAND)]
    amp = np.array([min(rad(SNAP_DEG), LIMITS.hi[GRIP] - q0[GRIP])])

    def fn(ph: np.ndarray) -> np.ndarray:
        return base + (0.5 - 0.5 * np.cos(2 * math.pi * ph))[:, None] * amp

    return _rhythm(q0, HAND, persistent, times, duration, SNAP_PERIOD_S, fn)


BEHAVIOURS: dict[str, Behaviour] = {
    "point_at": point_at,
    "wave": wave,
    "nod": nod,
    "shake": shake,
    "pick": pick,
    "place": place,
    "grip": grip,
    "release": release,
    "snap": snap,
}
