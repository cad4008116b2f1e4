"""CoCo's view of the generic motion maths (:mod:`robots.motion`): channels and limits bound to CoCo.

CoCo's motion library (:mod:`robots.coco.motions`, :mod:`robots.coco.gaits`) builds its motions
with :class:`Track` and :func:`transition` from here, which are the generic ones with CoCo's servo
limits filled in; :data:`CHANNEL_SERVOS` names the servos of CoCo's three motion channels.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cache

import numpy as np

from robots import motion as _motion
from robots.coco import ROBOT
from robots.motion import (
    DT,
    EASE_IN_S,
    SPEED_MARGIN,
    JointLimits,
    Motion,
    check_choice,
    check_count,
    check_finite,
    ease_in,
    min_jerk,
)

__all__ = [
    "CHANNEL_SERVOS",
    "check_choice",
    "check_count",
    "check_finite",
    "DT",
    "EASE_IN_S",
    "Motion",
    "SPEED_MARGIN",
    "Track",
    "check_start",
    "ease_in",
    "limits",
    "min_jerk",
    "transition",
]

#: CoCo's servo limits (radians, rad/s)
LIMITS = JointLimits.of_robot(ROBOT)
#: Channel -> servo indices (robot.toml [channels])
CHANNEL_SERVOS: dict[str, tuple[int, ...]] = {name: c.servos for name, c in ROBOT.channels.items()}


@cache
def limits() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mins, maxs, max_speeds) of all 12 servos, radians and rad/s."""
    return LIMITS.lo, LIMITS.hi, LIMITS.vmax


def check_start(start: Sequence[float] | np.ndarray) -> np.ndarray:
    """Validate the current joint targets of all 12 servos (within limits, finite)."""
    return _motion.check_start(start, LIMITS)


class Track(_motion.Track):
    """:class:`robots.motion.Track` within CoCo's limits."""

    def __init__(self, servos: Sequence[int], start: np.ndarray) -> None:
        super().__init__(servos, start, LIMITS)


def transition(start: Sequence[float] | np.ndarray, target: Sequence[float] | np.ndarray,
               servos: Sequence[int], *, max_speed: float | None = None, min_duration: float = 0.0) -> Motion:
    """:func:`robots.motion.transition` within CoCo's limits."""
    return _motion.transition(start, target, servos, LIMITS, max_speed=max_speed, min_duration=min_duration)
