"""MuJoCo helpers for CoCo: load the model, map servos to qpos/qvel/ctrl, place the robot on the floor."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from robots.coco import MJCF_PATH, ServoTable, load_servo_table

__all__ = ["CocoModel", "load_model"]

FOOT_SITES = ("fr_foot", "fl_foot", "bl_foot", "br_foot")


@dataclass
class CocoModel:
    """A compiled CoCo model with index arrays in servo-id order."""

    model: mujoco.MjModel
    table: ServoTable
    qpos_adr: np.ndarray  # qpos index of each servo's joint
    dof_adr: np.ndarray  # qvel index of each servo's joint
    act_id: np.ndarray  # actuator index of each servo
    foot_site_ids: np.ndarray
    foot_radius: float

    def new_data(self) -> mujoco.MjData:
        return mujoco.MjData(self.model)

    def place_on_floor(
        self, data: mujoco.MjData, q: Sequence[float] | np.ndarray, clearance: float = 0.0005
    ) -> None:
        """Reset ``data`` to joint angles ``q`` (servo order), ctrl = q, base upright with feet on the floor."""
        mujoco.mj_resetData(self.model, data)
        data.qpos[self.qpos_adr] = q
        data.ctrl[self.act_id] = q
        data.qpos[0:3] = (0.0, 0.0, 0.2)
        data.qpos[3:7] = (1.0, 0.0, 0.0, 0.0)
        mujoco.mj_kinematics(self.model, data)
        lowest = float(np.min(data.site_xpos[self.foot_site_ids, 2]))
        data.qpos[2] += self.foot_radius + clearance - lowest
        mujoco.mj_forward(self.model, data)


def load_model(table: ServoTable | None = None, scene: str = "empty") -> CocoModel:
    """Compile ``MJCF_PATH`` (plus the objects of ``scene``, see :mod:`robots.coco.scenes`)
    and resolve every servo's joint and actuator by name."""
    from robots.coco.scenes import build_model

    table = table or load_servo_table()
    model = build_model(scene)
    qpos, dof, act = [], [], []
    for s in table:
        j = model.joint(s.joint)
        qpos.append(int(j.qposadr[0]))
        dof.append(int(j.dofadr[0]))
        act.append(model.actuator(s.actuator).id)
    sites = np.array([model.site(n).id for n in FOOT_SITES])
    radius = float(model.geom("fr_foot").size[0])
    return CocoModel(model, table, np.array(qpos), np.array(dof), np.array(act), sites, radius)
