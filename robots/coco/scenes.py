"""CoCo's scenes (declared in robots/coco/robot.toml; built by the generic :mod:`robots.scenes`).

``bottles`` puts three light bottles (cylinders 12 cm tall, 2 cm radius, 30 g, each with a free
joint) in a row 25 cm in front of CoCo, 6 cm apart, for the long-horizon task "knock down the
bottles in front" (paper Task 31).
"""

from __future__ import annotations

import mujoco

from robots import scenes as _scenes
from robots.coco import ROBOT
from robots.scenes import TOPPLE_DEG, SceneObject, toppled

__all__ = ["BOTTLE_POSITIONS", "SCENES", "TOPPLE_DEG", "SceneObject", "build_model", "scene_objects", "toppled"]

SCENES = tuple(ROBOT.scenes)
BOTTLE_POSITIONS = tuple((o.pos[0], o.pos[1]) for o in ROBOT.scenes["bottles"].objects)
BOTTLE_RADIUS = ROBOT.scenes["bottles"].objects[0].size[0]
BOTTLE_HALF_HEIGHT = ROBOT.scenes["bottles"].objects[0].size[1]
BOTTLE_MASS = ROBOT.scenes["bottles"].objects[0].mass


def build_model(scene: str = "empty") -> mujoco.MjModel:
    """CoCo's model with the scene's objects added; ValueError names the valid scenes."""
    if scene not in ROBOT.scenes:
        raise ValueError(f"unknown scene {scene!r}; valid: {', '.join(ROBOT.scenes)}")
    return _scenes.build_model(ROBOT, scene)


def scene_objects(model: mujoco.MjModel) -> list[SceneObject]:
    """The movable objects (the bottles) in ``model``."""
    return _scenes.scene_objects(model, ROBOT.scenes["bottles"])
