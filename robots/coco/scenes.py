"""Scenes: objects added to CoCo's MJCF world (``--scene NAME`` on the board).

``bottles`` puts three light bottles (cylinders 12 cm tall, 2 cm radius, 30 g,
each with a free joint) in a row 25 cm in front of CoCo, 6 cm apart, for the
long-horizon task "knock down the bottles in front" (paper Task 31). The objects
are added with MuJoCo's model-editing API (``mujoco.MjSpec``), so ``coco.xml``
stays the robot alone. A bottle counts as toppled when its axis leans more than
:data:`TOPPLE_DEG` from vertical (simulation ground truth).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from robots.coco import MJCF_PATH

SCENES = ("empty", "bottles")
#: a bottle whose axis leans more than this from vertical has toppled
TOPPLE_DEG = 45.0


@dataclass(frozen=True)
class SceneObject:
    """One movable object: MJCF body name, its free joint's qpos address."""

    name: str
    qpos_adr: int


BOTTLE_RADIUS = 0.02
BOTTLE_HALF_HEIGHT = 0.06
BOTTLE_MASS = 0.03
BOTTLE_POSITIONS = ((0.25, -0.06), (0.25, 0.0), (0.25, 0.06))


def build_model(scene: str = "empty") -> mujoco.MjModel:
    """CoCo's model with the scene's objects added; ValueError names the valid scenes."""
    if scene not in SCENES:
        raise ValueError(f"unknown scene {scene!r}; valid: {', '.join(SCENES)}")
    if scene == "empty":
        return mujoco.MjModel.from_xml_path(str(MJCF_PATH))
    spec = mujoco.MjSpec.from_file(str(MJCF_PATH))
    for i, (x, y) in enumerate(BOTTLE_POSITIONS):
        body = spec.worldbody.add_body(name=f"bottle_{i}", pos=[x, y, BOTTLE_HALF_HEIGHT + 1e-4])
        body.add_freejoint(name=f"bottle_{i}_free")
        body.add_geom(name=f"bottle_{i}_geom", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                      size=[BOTTLE_RADIUS, BOTTLE_HALF_HEIGHT, 0], mass=BOTTLE_MASS,
                      friction=[0.6, 0.005, 0.0001], rgba=[0.2, 0.6, 0.9, 1])
    return spec.compile()


def scene_objects(model: mujoco.MjModel) -> list[SceneObject]:
    """The scene's movable objects (bodies named ``bottle_N``) in the model."""
    out = []
    for j in range(model.njnt):
        name = model.joint(j).name
        if name.startswith("bottle_") and name.endswith("_free"):
            out.append(SceneObject(name[: -len("_free")], int(model.jnt_qposadr[j])))
    return out


def toppled(qpos: np.ndarray, objects: list[SceneObject]) -> int:
    """How many objects lean more than TOPPLE_DEG (their local z axis vs world z)."""
    count = 0
    for o in objects:
        w, x, y, z = qpos[o.qpos_adr + 3: o.qpos_adr + 7]
        # world z component of the body's z axis: 1 - 2(x^2 + y^2) for a unit quaternion
        cos_tilt = 1.0 - 2.0 * (x * x + y * y) / max(w * w + x * x + y * y + z * z, 1e-12)
        if cos_tilt < np.cos(np.radians(TOPPLE_DEG)):
            count += 1
    return count
