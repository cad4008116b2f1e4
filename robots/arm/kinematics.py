"""The arm's kinematics: where its grasp point is for given joint angles, and the joint angles that
put it at a point with the hand at a given pitch (closed form).

Geometry (metres), read from the MJCF (``arm.xml``) by :meth:`ArmGeometry.from_mjcf`, so the
model and these formulas cannot drift apart; the lengths themselves are the SO-101's public
link offsets, rounded (see the comment at the top of ``arm.xml``):

- the pan axis is vertical through the base body; the shoulder_lift axis sits ``lift_r`` = 0.0304
  forward of it and ``lift_z`` = 0.1166 above the base (0.0624 + 0.0542);
- upper arm ``l1`` = 0.116 (shoulder_lift -> elbow_flex), forearm ``l2`` = 0.135 (elbow_flex ->
  wrist_flex), hand ``l3`` = 0.13 (wrist_flex -> the grasp point between the jaws, on the
  wrist_roll axis).

In the arm's vertical plane (after the pan) a direction is measured by its angle *below* the
horizontal, ``a`` (so the unit vector is ``(cos a, -sin a)`` in (radial, up)). With the joint
conventions of ``arm.xml``: the upper arm points at ``lift - 90 deg``, the forearm at ``lift +
elbow``, the hand at ``lift + elbow + wrist_flex`` (90 deg: straight down).

Inverse kinematics (:func:`ArmGeometry.solve`): the pan is ``atan2(dy, dx)`` of the target; the
wrist_flex axis must be ``l3`` back along the wanted hand direction; shoulder_lift and elbow_flex
put it there by the planar two-link solution (law of cosines; e.g. J. J. Craig, *Introduction to
Robotics*, 3rd ed., section 4.4), elbow up (the forearm reaches down from above, the way a desk arm
reaches onto a table); wrist_flex takes the rest of the hand's pitch. The wrist roll that lines the
jaws up with a box's faces follows from the hand frame ``Rz(pan) Ry(pitch) Rx(roll)``: pointing
down, the jaws close along the direction at yaw ``pan + 90 deg - roll``, so a box at yaw ``psi``
needs ``roll = pan - psi`` modulo 90 deg (:func:`ArmGeometry.square_roll` takes the smallest).

Written by hand: a five-joint arm whose three pitch joints are parallel has this closed-form
solution, a few lines of trigonometry; a numerical IK library (ikpy, pink, mink) would add a
dependency and iterations, and give no clearer answer to "is this point reachable".
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["ArmGeometry", "Unreachable", "DOWN"]

#: the hand's pitch when it points straight down (rad below the horizontal)
DOWN = math.pi / 2


class Unreachable(ValueError):
    """No joint angles within the limits put the grasp point there (the message says why)."""


@dataclass(frozen=True)
class ArmGeometry:
    """The arm's link lengths (m), its base position in the world (m) and its joint limits (rad,
    order: shoulder_pan, shoulder_lift, elbow_flex, wrist_flex, wrist_roll)."""

    base: tuple[float, float, float]
    lift_r: float
    lift_z: float
    l1: float
    l2: float
    l3: float
    lo: tuple[float, ...]
    hi: tuple[float, ...]

    @classmethod
    def from_mjcf(cls, path: Path) -> ArmGeometry:
        """Read the geometry from the arm's MJCF (its body offsets, the ``grasp`` site and the joint
        ranges); ValueError when the model is not shaped as this module assumes."""
        import mujoco

        m = mujoco.MjModel.from_xml_path(str(path))

        def pos(body: str) -> np.ndarray:
            return np.asarray(m.body(body).pos, dtype=float)

        def axis(joint: str) -> tuple[float, ...]:
            return tuple(float(v) for v in m.joint(joint).axis)

        expect = {"shoulder_pan": (0.0, 0.0, 1.0), "shoulder_lift": (0.0, 1.0, 0.0), "elbow_flex": (0.0, 1.0, 0.0),
                  "wrist_flex": (0.0, 1.0, 0.0), "wrist_roll": (1.0, 0.0, 0.0)}
        for j, ax in expect.items():
            if axis(j) != ax:
                raise ValueError(f"{path.name}: joint {j} has axis {axis(j)}, kinematics.py assumes {ax}")
        shoulder, upper, fore, wrist, hand = (pos(b) for b in ("shoulder", "upper_arm", "forearm", "wrist", "hand"))
        grasp = np.asarray(m.site("grasp").pos, dtype=float)
        if (abs(shoulder[0]) + abs(shoulder[1]) + abs(upper[1]) + abs(fore[0]) + abs(fore[1]) + abs(wrist[1])
                + abs(wrist[2]) + float(np.abs(hand).sum()) + abs(grasp[1]) + abs(grasp[2])) > 1e-9:
            raise ValueError(f"{path.name}: the arm's bodies are not in one plane as kinematics.py assumes")
        names = tuple(expect)
        lo = tuple(float(m.joint(j).range[0]) for j in names)
        hi = tuple(float(m.joint(j).range[1]) for j in names)
        base = tuple(float(v) for v in pos("base"))
        return cls(base=(base[0], base[1], base[2]), lift_r=float(upper[0]), lift_z=float(shoulder[2] + upper[2]),
                   l1=float(fore[2]), l2=float(wrist[0]), l3=float(grasp[0]), lo=lo, hi=hi)

    # -- forward ------------------------------------------------------------------------------------
    def forward(self, q: np.ndarray | Sequence[float]) -> tuple[np.ndarray, float]:
        """Grasp point (world x, y, z in m) and the hand's pitch below the horizontal (rad) for the
        joint angles ``q`` (rad; the first four are used: pan, lift, elbow, wrist_flex)."""
        pan, lift, elbow, wflex = (float(v) for v in q[:4])
        a1, a2 = lift - DOWN, lift + elbow
        a3 = a2 + wflex
        r = self.lift_r + self.l1 * math.cos(a1) + self.l2 * math.cos(a2) + self.l3 * math.cos(a3)
        z = self.lift_z - self.l1 * math.sin(a1) - self.l2 * math.sin(a2) - self.l3 * math.sin(a3)
        bx, by, bz = self.base
        return np.array([bx + r * math.cos(pan), by + r * math.sin(pan), bz + z]), a3

    # -- inverse ------------------------------------------------------------------------------------
    def solve(self, point: np.ndarray | Sequence[float], pitch: float = DOWN, roll: float = 0.0) -> np.ndarray:
        """Joint angles (rad: pan, lift, elbow, wrist_flex, wrist_roll) that put the grasp point at
        ``point`` (world m) with the hand ``pitch`` rad below the horizontal and the wrist at
        ``roll``; :class:`Unreachable` when the point is out of reach or a joint would leave its range."""
        x, y, z = (float(v) - b for v, b in zip(point, self.base))
        pan = math.atan2(y, x) if math.hypot(x, y) > 1e-9 else 0.0
        r = math.hypot(x, y)
        # the wrist_flex axis, l3 back along the hand
        wr = r - self.l3 * math.cos(pitch) - self.lift_r
        wz = z + self.l3 * math.sin(pitch) - self.lift_z
        d = math.hypot(wr, wz)
        where = f"({point[0]:.3f}, {point[1]:.3f}, {point[2]:.3f}) m"
        if d > self.l1 + self.l2 - 1e-9:
            raise Unreachable(f"{where} is out of reach ({d * 1000:.0f} mm from the shoulder, the arm spans "
                              f"{(self.l1 + self.l2) * 1000:.0f} mm)")
        if d < abs(self.l1 - self.l2) + 1e-9:
            raise Unreachable(f"{where} is too close to the shoulder to reach")
        aw = math.atan2(-wz, wr)  # direction shoulder -> wrist, below the horizontal
        psi = math.acos(max(-1.0, min(1.0, (self.l1 ** 2 + d * d - self.l2 ** 2) / (2 * self.l1 * d))))
        a1 = aw - psi  # elbow up: the upper arm above the shoulder-wrist line
        lift = a1 + DOWN
        er, ez = self.l1 * math.cos(a1), -self.l1 * math.sin(a1)
        a2 = math.atan2(-(wz - ez), wr - er)
        elbow = a2 - lift
        wflex = pitch - a2
        q = np.array([pan, lift, _wrap(elbow), _wrap(wflex), roll])
        names = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll")
        for name, v, lo, hi in zip(names, q, self.lo, self.hi):
            if not lo - 1e-9 <= v <= hi + 1e-9:
                raise Unreachable(f"{where}: {name} would need {math.degrees(v):.1f} deg, outside "
                                  f"[{math.degrees(lo):.1f}, {math.degrees(hi):.1f}]")
        return q

    @staticmethod
    def square_roll(pan: float, yaw: float = 0.0) -> float:
        """The wrist roll (rad, |roll| <= 45 deg) that lines the jaws up with the faces of a box at
        ``yaw`` (rad) when the hand points down at pan angle ``pan`` (rad)."""
        quarter = math.pi / 2
        rel = pan - yaw
        return rel - quarter * round(rel / quarter)


def _wrap(a: float) -> float:
    """``a`` in (-pi, pi]."""
    return math.atan2(math.sin(a), math.cos(a))
