"""Scenes: objects added to a robot's MJCF world (``--scene NAME`` on the board), built from data.

A robot's ``robot.toml`` declares its scenes (``[scenes.NAME]`` with ``[[scenes.NAME.objects]]``,
:class:`robots.description.SceneObjectSpec`); every robot has ``empty`` (the MJCF as it is). The
objects are added with MuJoCo's model-editing API (``mujoco.MjSpec``), so the robot's MJCF stays the
robot alone: a body named as the object, a free joint ``NAME_free`` for a movable one, and a geom
``NAME_geom``. An object marked ``topples`` counts as toppled when its axis leans more than
:data:`TOPPLE_DEG` from vertical (simulation ground truth; SIM_STATE's ``toppled``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from robots.datatypes import RobotData, SceneSpec

__all__ = ["SceneObject", "TOPPLE_DEG", "build_model", "scene_objects", "toppled"]

#: an object whose axis leans more than this from vertical has toppled
TOPPLE_DEG = 45.0

_GEOMS = {"box": mujoco.mjtGeom.mjGEOM_BOX, "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
          "sphere": mujoco.mjtGeom.mjGEOM_SPHERE}


@dataclass(frozen=True)
class SceneObject:
    """One movable object in a compiled model: body name, its free joint's qpos address, whether it
    counts for ``toppled``."""

    name: str
    qpos_adr: int
    topples: bool = True


def _quat(euler_deg: Sequence[float]) -> list[float]:
    q = np.zeros(4)
    mujoco.mju_euler2Quat(q, np.radians(np.asarray(euler_deg, dtype=float)), "xyz")
    return q.tolist()


def build_model(robot: RobotData, scene: str | None = None) -> mujoco.MjModel:
    """``robot``'s model with the scene's objects added; KeyError names the valid scenes."""
    spec_scene: SceneSpec = robot.scene(scene)
    if not spec_scene.objects:
        return mujoco.MjModel.from_xml_path(str(robot.mjcf))
    spec = mujoco.MjSpec.from_file(str(robot.mjcf))
    for o in spec_scene.objects:
        kw = {"name": o.name, "pos": list(o.pos)}
        if any(o.euler_deg):
            kw["quat"] = _quat(o.euler_deg)
        body = spec.worldbody.add_body(**kw)
        if o.free:
            body.add_freejoint(name=f"{o.name}_free")
        size = [*o.size, *([0.0] * (3 - len(o.size)))]
        geom = {"name": f"{o.name}_geom", "type": _GEOMS[o.shape], "size": size, "friction": list(o.friction),
                "rgba": list(o.rgba)}
        if o.mass is not None:
            geom["mass"] = o.mass
        body.add_geom(**geom)
    return spec.compile()


def scene_objects(model: mujoco.MjModel, spec: SceneSpec | None = None) -> list[SceneObject]:
    """The movable objects of ``spec`` (all its free objects) found in ``model``."""
    if spec is None:
        return []
    out = []
    for o in spec.objects:
        if not o.free:
            continue
        j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{o.name}_free")
        if j >= 0:
            out.append(SceneObject(o.name, int(model.jnt_qposadr[j]), o.topples))
    return out


def toppled(qpos: np.ndarray, objects: Sequence[SceneObject]) -> int:
    """How many ``topples`` objects lean more than TOPPLE_DEG (their local z axis vs world z)."""
    count = 0
    limit = math.cos(math.radians(TOPPLE_DEG))
    for o in objects:
        if not o.topples:
            continue
        w, x, y, z = qpos[o.qpos_adr + 3: o.qpos_adr + 7]
        # world z component of the body's z axis: 1 - 2(x^2 + y^2) for a unit quaternion
        cos_tilt = 1.0 - 2.0 * (x * x + y * y) / max(w * w + x * x + y * y + z * z, 1e-12)
        if cos_tilt < limit:
            count += 1
    return count


def object_positions(data: mujoco.MjData, objects: Sequence[SceneObject]) -> dict[str, tuple[float, float, float]]:
    """World position (m) of each movable object now."""
    return {o.name: tuple(float(v) for v in data.qpos[o.qpos_adr:o.qpos_adr + 3]) for o in objects}  # type: ignore[misc]
