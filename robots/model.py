"""A robot's compiled MuJoCo model with its servos resolved: what the board and the video use.

:func:`load_model` compiles the robot's MJCF with a scene (:mod:`robots.scenes`) and maps every
servo (in servo-id order) to its joint's qpos/qvel addresses and its actuator. A floating robot
(``[base] floating = true``: its root has a free joint) is placed upright with its lowest foot site
on the floor; a fixed one (an arm) keeps the MJCF's placement. :meth:`RobotModel.base_pose` reads
the root's position and orientation either way (SIM_STATE and the IMU report it).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import mujoco
import numpy as np

from robots.datatypes import RobotData, ServoTable
from robots.scenes import SceneObject, build_model, scene_objects

__all__ = ["RobotModel", "load_model"]


@dataclass
class RobotModel:
    """A compiled model with index arrays in servo-id order.

    ``root_qpos``: qpos address of the free joint of a floating robot (None for a fixed base);
    ``root_body``: the body whose pose SIM_STATE reports (the free joint's body, else the first
    body under the world).
    """

    robot: RobotData
    model: mujoco.MjModel
    table: ServoTable
    qpos_adr: np.ndarray  # qpos index of each servo's joint
    dof_adr: np.ndarray  # qvel index of each servo's joint
    act_id: np.ndarray  # actuator index of each servo
    foot_site_ids: np.ndarray
    foot_radius: float
    root_qpos: int | None
    root_body: int
    objects: list[SceneObject] = field(default_factory=list)

    def new_data(self) -> mujoco.MjData:
        return mujoco.MjData(self.model)

    @property
    def floating(self) -> bool:
        return self.root_qpos is not None

    def place_on_floor(self, data: mujoco.MjData, q: Sequence[float] | np.ndarray, clearance: float = 0.0005) -> None:
        """Reset ``data`` to joint angles ``q`` (servo order), ctrl = q; a floating base upright with
        its lowest foot site ``foot_radius + clearance`` above the floor."""
        mujoco.mj_resetData(self.model, data)
        data.qpos[self.qpos_adr] = q
        data.ctrl[self.act_id] = q
        r = self.root_qpos
        if r is not None:
            data.qpos[r:r + 3] = (0.0, 0.0, self.robot.base.spawn_height)
            data.qpos[r + 3:r + 7] = (1.0, 0.0, 0.0, 0.0)
            if len(self.foot_site_ids):
                mujoco.mj_kinematics(self.model, data)
                lowest = float(np.min(data.site_xpos[self.foot_site_ids, 2]))
                data.qpos[r + 2] += self.foot_radius + clearance - lowest
        mujoco.mj_forward(self.model, data)

    def base_pose(self, data: mujoco.MjData) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """(position m, quaternion w x y z) of the root: the free joint's qpos, or the root body's frame."""
        r = self.root_qpos
        if r is not None:
            q = data.qpos
            return (float(q[r]), float(q[r + 1]), float(q[r + 2])), \
                (float(q[r + 3]), float(q[r + 4]), float(q[r + 5]), float(q[r + 6]))
        b = self.root_body
        p, quat = data.xpos[b], data.xquat[b]
        return (float(p[0]), float(p[1]), float(p[2])), (float(quat[0]), float(quat[1]), float(quat[2]), float(quat[3]))

    def set_state(self, data: mujoco.MjData, base: Sequence[float] | None, joints: Sequence[float],
                  objects: Mapping[str, Sequence[float]] | None = None) -> None:
        """Put a recorded state into ``data`` (base = x y z qw qx qy qz for a floating robot; ``objects``:
        movable scene objects' poses by name, x y z qw qx qy qz, others stay put) and run forward
        kinematics (for rendering)."""
        r = self.root_qpos
        if r is not None and base is not None:
            data.qpos[r:r + 7] = base
        data.qpos[self.qpos_adr] = joints
        for o in self.objects if objects else ():
            pose = objects.get(o.name) if objects else None
            if pose is not None and len(pose) == 7:
                data.qpos[o.qpos_adr:o.qpos_adr + 7] = pose
        mujoco.mj_forward(self.model, data)


def load_model(robot: RobotData, scene: str | None = None) -> RobotModel:
    """Compile ``robot``'s MJCF with ``scene``'s objects and resolve every servo's joint and actuator."""
    table = robot.servos
    model = build_model(robot, scene)
    qpos, dof, act = [], [], []
    for s in table:
        j = model.joint(s.joint)
        qpos.append(int(j.qposadr[0]))
        dof.append(int(j.dofadr[0]))
        act.append(model.actuator(s.actuator).id)
    sites = np.array([model.site(n).id for n in robot.base.feet], dtype=int)
    root_qpos: int | None = None
    root_body = 1 if model.nbody > 1 else 0
    if robot.base.floating:
        for j in range(model.njnt):
            # the robot's bodies come first (scene objects are appended after the MJCF's)
            if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE and model.body_parentid[model.jnt_bodyid[j]] == 0:
                root_qpos, root_body = int(model.jnt_qposadr[j]), int(model.jnt_bodyid[j])
                break
    spec = robot.scene(scene)
    return RobotModel(robot, model, table, np.array(qpos), np.array(dof), np.array(act), sites,
                      robot.base.foot_radius, root_qpos, root_body, scene_objects(model, spec))
