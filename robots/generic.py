"""The generic functions every robot has: ``pose`` and ``joint_move`` (stubs and behaviours).

``<pose name="P" duration="S"/>`` moves every servo to the named pose P; ``<joint_move joint="J"
deg="X" duration="S"/>`` moves one servo to X degrees (a joint angle, the servo table's units).
Both are minimum-jerk moves that take ``duration`` seconds or longer when a servo's speed limit
needs it (:func:`robots.motion.transition`), on the ``joints`` channel. As a parent element they hold
the target until reset. Built per robot: the pose and joint names become ``Literal`` types, so the
mapper refuses a name the robot does not have before anything moves.

No ``from __future__ import annotations`` here: the stubs are made at run time with the robot's
names as real types, and the shell reads them with ``typing.get_type_hints``.
"""

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import numpy as np
from annotated_types import Interval

from robots.datatypes import RobotData
from robots.stubs import stub
from robots.motion import JointLimits, Motion, check_finite, transition

__all__ = ["GENERIC_CHANNEL", "JointDegrees", "generic_behaviours", "generic_module", "joint_range_text"]

#: the channel the generic functions run on
GENERIC_CHANNEL = "joints"
#: bounds of ``duration`` (s)
Seconds = Annotated[float, Interval(ge=0.0, le=120.0)]


def joint_range_text(value: float, name: str, lo_deg: float, hi_deg: float) -> str | None:
    """None when ``value`` (deg) is inside ``[lo_deg, hi_deg]``, else why, naming the joint's own range:
    ``"[-97, 97] for joint elbow_flex"`` (what follows "is out of range" in the mapper's message)."""
    if lo_deg - 1e-6 <= value <= hi_deg + 1e-6:
        return None
    return f"[{lo_deg:.4g}, {hi_deg:.4g}] for joint {name}"


@dataclass(frozen=True)
class JointDegrees:
    """The bound of ``joint_move``'s ``deg``: the range of the joint its ``joint`` argument names.

    ``ge``/``le`` are the widest range (what ``robots show`` and the prompt print as the parameter's span);
    the mapper (:func:`host.shell.mapper.map_args`) checks the value against the named joint's own range
    with :meth:`out_of_range`, so a message never names another joint's range. Not an ``annotated_types``
    bound on purpose: the MCP tool schema leaves it out (JSON Schema cannot make a bound depend on another
    argument), and the shell's message says which joint and which range."""

    ge: float
    le: float
    ranges: tuple[tuple[str, float, float], ...]  # (servo or joint name, lo deg, hi deg)
    joint_param: str = "joint"

    def out_of_range(self, value: Any, args: Mapping[str, Any]) -> str | None:
        """None when ``value`` is inside the range of the joint ``args[joint_param]`` names, else the text that
        follows "is out of range" (:func:`joint_range_text`)."""
        joint = args.get(self.joint_param)
        for name, lo, hi in self.ranges:
            if name == joint:
                return joint_range_text(float(value), name, lo, hi)
        return None


def _hold_end(m: Motion) -> Motion:
    """The persistent form of a move: hold its last sample (a loop of one sample)."""
    if len(m.t) < 2:
        t = np.array([0.0, 0.01])
        q = np.vstack([m.q[0], m.q[0]])
        return Motion(m.servos, t, q, 0.01)
    return Motion(m.servos, m.t, m.q, float(m.t[-1]))


def generic_behaviours(robot: RobotData) -> Mapping[str, Callable[..., Motion]]:
    """``pose`` and ``joint_move`` for ``robot``: ``gen(start, *, persistent=False, **params) -> Motion``."""
    limits = JointLimits.of_robot(robot)
    table = robot.servos
    every = tuple(range(robot.servo_count))

    def pose(start: np.ndarray, *, persistent: bool = False, name: str = robot.start_pose,
             duration: float = 1.0) -> Motion:
        check_finite(duration=duration)
        if duration < 0:
            raise ValueError(f"duration must be >= 0 s, got {duration}")
        target = robot.pose(name)
        m = transition(start, target, every, limits, min_duration=float(duration))
        return _hold_end(m) if persistent else m

    def joint_move(start: np.ndarray, *, persistent: bool = False, joint: str = "", deg: float = 0.0,
                   duration: float = 1.0) -> Motion:
        check_finite(deg=deg, duration=duration)
        if duration < 0:
            raise ValueError(f"duration must be >= 0 s, got {duration}")
        try:
            s = table.by_name(joint)
        except KeyError:
            try:
                s = table.by_joint(joint)
            except KeyError:
                raise ValueError(f"{robot.name} has no joint {joint!r}; joints: {', '.join(table.names)}") from None
        why = joint_range_text(deg, s.name, math.degrees(s.min), math.degrees(s.max))
        if why is not None:  # the mapper refuses it first (JointDegrees); a caller in Python gets the same line
            raise ValueError(f"<joint_move> deg={deg:g} is out of range {why}")
        m = transition(start, [math.radians(deg)], (s.index,), limits, min_duration=float(duration))
        return _hold_end(m) if persistent else m

    return {"pose": pose, "joint_move": joint_move}


def generic_module(robot: RobotData) -> type:
    """The ``joints`` module class of ``robot``: the stubs ``pose`` and ``joint_move`` with its names."""
    table = robot.servos
    pose_names: Any = Literal.__getitem__(tuple(robot.poses))  # type: ignore[attr-defined]
    joint_names: Any = Literal.__getitem__(table.names)  # type: ignore[attr-defined]
    ranges = ", ".join(f"{s.name} {math.degrees(s.min):.4g}..{math.degrees(s.max):.4g}" for s in table)
    widest = max(max(abs(math.degrees(s.min)), abs(math.degrees(s.max))) for s in table)
    bound = float(math.ceil(widest))

    def pose(self, name, duration=1.0) -> None:  # type: ignore[no-untyped-def]
        pass

    pose.__annotations__ = {"name": pose_names, "duration": Seconds, "return": None}
    pose.__doc__ = (f"Move every servo smoothly to the named pose in `duration` seconds (longer if a servo's "
                    f"speed limit needs it); poses: {', '.join(robot.poses)}.")

    def joint_move(self, joint, deg, duration=1.0) -> None:  # type: ignore[no-untyped-def]
        pass

    own = tuple((n, math.degrees(sv.min), math.degrees(sv.max))
                for sv in table for n in dict.fromkeys((sv.name, sv.joint)))  # a servo by its name or its joint's
    joint_move.__annotations__ = {"joint": joint_names, "deg": Annotated[float, JointDegrees(-bound, bound, own)],
                                  "duration": Seconds, "return": None}
    joint_move.__doc__ = (f"Move one joint to `deg` degrees (a joint angle) in `duration` seconds; ranges in "
                          f"degrees: {ranges}.")
    for fn in (pose, joint_move):
        fn.__module__ = __name__
        fn.__qualname__ = f"Joints.{fn.__name__}"
        stub(GENERIC_CHANNEL)(fn)
    return type("Joints", (), {"__doc__": "Whole-robot moves (every servo of the robot).", "__module__": __name__,
                               "pose": pose, "joint_move": joint_move})
