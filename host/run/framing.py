"""The video's camera and floor for a fixed-base robot that states no ``[view]``: framed from its model.

A third-party arm's MJCF often has no floor and no camera placement the follow camera could use; with the
defaults (0.75 m from the base, looking at 5 cm above it) a tall arm is cut off and a small one is a speck
in a black void. :func:`frame_fixed_base` instead puts the model at the neutral pose
(``mj_forward``), bounds every visible geom of a body (groups 0-2, not transparent; the world body's own
geoms are scenery and left out) by its own box turned into the world's axes (``geom_aabb`` about
``geom_xpos``/``geom_xmat``), and aims the free camera at the
box's centre from the distance at which its bounding sphere fills the view (``vis.global.fovy``), with a
little margin. When the model has no floor (no plane, no geom on the world body, no static scene object
such as a table) it also returns a floor just under the box, which :func:`add_floor` draws into the
rendered scene only: a visual geom (``mjv_initGeom``), never part of the physics the board simulated.

:mod:`host.run.video` uses the framed camera only when the robot package has no ``[view]`` (one it states
wins); a floating robot keeps the camera that follows its base.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["FLOOR_RGBA", "Framing", "add_floor", "frame_fixed_base"]

#: the drawn floor: a light grey that neither a dark nor a bright robot disappears against
FLOOR_RGBA = (0.62, 0.64, 0.68, 1.0)
#: the bounding sphere's radius x this fills the view (some air around the robot)
MARGIN = 1.15
#: the drawn floor's half size, in bounding-sphere radii (at least 5 m): far enough to reach the horizon
FLOOR_RADII = 40
#: geom groups MuJoCo draws by default (``mjvOption.geomgroup``: 0, 1 and 2)
VISIBLE_GROUPS = 3


@dataclass(frozen=True)
class Framing:
    """Where the camera looks (``lookat`` m, ``distance`` m) and the floor to draw: ``floor_z`` (None: the
    model has one), ``floor_half`` its half size (m); ``box``: the visible geoms' bounds (lo xyz, hi xyz)."""

    lookat: tuple[float, float, float]
    distance: float
    floor_z: float | None
    floor_half: float
    box: tuple[tuple[float, float, float], tuple[float, float, float]]


def _has_floor(model: Any, static_objects: int) -> bool:
    """A plane, a geom of the world body itself (a floor or table box, scenery) or a static scene object."""
    import mujoco

    planes = np.asarray(model.geom_type) == int(mujoco.mjtGeom.mjGEOM_PLANE)
    world = np.asarray(model.geom_bodyid) == 0
    return bool(planes.any() or world.any()) or static_objects > 0


def frame_fixed_base(model: Any, data: Any, qpos_adr: Sequence[int] | np.ndarray, q: Sequence[float] | np.ndarray,
                     *, static_objects: int = 0, fovy_deg: float | None = None) -> Framing:
    """The framing of ``model`` with its servos' joints (qpos addresses ``qpos_adr``) at ``q`` (rad; the
    neutral pose); ``data`` is used for the forward kinematics. ``static_objects``: how many objects the
    scene welds to the world (a table or a floor: no floor is drawn then)."""
    import mujoco

    mujoco.mj_resetData(model, data)
    data.qpos[list(qpos_adr)] = q
    mujoco.mj_forward(model, data)
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for g in range(model.ngeom):
        if (int(model.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_PLANE) or int(model.geom_group[g]) >= VISIBLE_GROUPS
                or int(model.geom_bodyid[g]) == 0):  # the world body's geoms are scenery (a floor box, a table)
            continue
        if float(model.geom_rgba[g, 3]) <= 0.0 and int(model.geom_matid[g]) < 0:
            continue
        # the geom's own box (geom_aabb: centre and half sizes in its frame) turned into the world's axes
        rot = np.asarray(data.geom_xmat[g], dtype=float).reshape(3, 3)
        c = np.asarray(data.geom_xpos[g], dtype=float) + rot @ np.asarray(model.geom_aabb[g, :3], dtype=float)
        h = np.abs(rot) @ np.asarray(model.geom_aabb[g, 3:], dtype=float)
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(h))):
            continue
        lo, hi = np.minimum(lo, c - h), np.maximum(hi, c + h)
    if not np.all(np.isfinite(lo)):  # nothing visible: MuJoCo's own estimate of the model's size
        c, e = np.asarray(model.stat.center, dtype=float), float(model.stat.extent) or 0.5
        lo, hi = c - e / 2, c + e / 2
    center = (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 0.02)
    fovy = math.radians(float(model.vis.global_.fovy) if fovy_deg is None else fovy_deg)
    distance = radius * MARGIN / math.sin(fovy / 2)
    floor_z = None if _has_floor(model, static_objects) else float(lo[2]) - 0.001
    return Framing((float(center[0]), float(center[1]), float(center[2])), distance, floor_z,
                   max(FLOOR_RADII * radius, 5.0),
                   (tuple(float(v) for v in lo), tuple(float(v) for v in hi)))  # type: ignore[arg-type]


def add_floor(scene: Any, framing: Framing) -> None:
    """Draw the framing's floor (if it has one) into ``scene`` (an ``mjvScene`` after ``update_scene``)."""
    import mujoco

    if framing.floor_z is None or scene.ngeom >= scene.maxgeom:
        return
    x, y, _ = framing.lookat
    half = framing.floor_half
    geom = scene.geoms[scene.ngeom]
    mujoco.mjv_initGeom(geom, int(mujoco.mjtGeom.mjGEOM_PLANE), np.array([half, half, half / 20]),
                        np.array([x, y, framing.floor_z]), np.eye(3).flatten(), np.array(FLOOR_RGBA, dtype=np.float32))
    scene.ngeom += 1
