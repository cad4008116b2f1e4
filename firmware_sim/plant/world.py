"""The plant's world: the robot's MuJoCo model driven by the servos' goal registers.

Per control period (one call of :meth:`World.step`): each servo's goal position (steps) becomes a
joint angle (``neutral + direction * (steps - centre) * step``), the servo's deadband holds it at
the measured position while the error is below the table's deadband (what the Python board's
servo model does per tick, here inside the servo where a real one does it), MuJoCo steps
``substeps`` times, and the present registers (position, speed, load), the IMU's roll/pitch/yaw
and the probe's ground truth are refreshed from the new state.

Conversions are the inverse of the C firmware's generated servo table
(:mod:`firmware_sim.cfirmware.servo_table`): present position ``centre + direction *
round((q - neutral) / step)``, speed in steps/s, load in 0.1 % of the servo's full torque.
"""

from __future__ import annotations

import math
import struct

import mujoco
import numpy as np

from firmware_sim.board import quat_to_rpy
from firmware_sim.cfirmware.servo_table import STEP_CENTRE, _step_range, load_full_scale
from firmware_sim.plant.devices import REG, ImuDevice, ProbeDevice, ServoDevice
from firmware_sim.plant.feetech import to_sign_magnitude
from robots.description import Robot
from robots.scenes import toppled

__all__ = ["World"]


def _q16(v: float) -> int:
    return max(-32767, min(32767, int(round(v * 10_000))))


class World:
    """MuJoCo physics behind the bus devices (ids 1..N, the IMU, the probe)."""

    def __init__(self, robot: Robot, *, scene: str | None = None, rate_hz: int = 500, dt: float = 0.002) -> None:
        self.robot = robot
        self.table = robot.servos
        self.cm = robot.model(scene or robot.default_scene)
        self.model = self.cm.model
        self.model.opt.timestep = dt
        self.data = self.cm.new_data()
        self.n = len(self.table)
        self.step_rad = self.table.model.resolution
        self.deadband = self.table.model.deadband
        self.substeps = max(1, round(1.0 / (rate_hz * dt)))
        self.period_us = 1_000_000 // rate_hz
        neutral = np.array(self.table.neutral)
        self.cm.place_on_floor(self.data, neutral)
        self.full = load_full_scale(robot)
        self.servos: list[ServoDevice] = []
        for s in self.table:
            lo, hi = _step_range(s.neutral, s.min, s.max, s.direction, self.step_rad)
            self.servos.append(ServoDevice(s.id, lo, hi, STEP_CENTRE))
        self.imu = ImuDevice()
        self.probe = ProbeDevice()
        self.devices = {d.id: d for d in (*self.servos, self.imu, self.probe)}
        self.time_us = 0
        self.steps = 0
        for i, s in enumerate(self.table):
            self.servos[i].set_u16(REG.GOAL_POSITION, self._to_steps(i, s.neutral))
        self.stale = False
        self.refresh()

    # -- conversions ---------------------------------------------------------------------------
    def _to_steps(self, i: int, q: float) -> int:
        s = self.table[i]
        return max(0, min(4095, STEP_CENTRE + s.direction * int(round((q - s.neutral) / self.step_rad))))

    def goal_rad(self, i: int) -> float:
        s = self.table[i]
        return s.neutral + s.direction * (self.servos[i].goal - STEP_CENTRE) * self.step_rad

    def positions(self) -> np.ndarray:
        """Joint angles (rad), servo order, as MuJoCo has them."""
        return self.data.qpos[self.cm.qpos_adr].copy()

    # -- physics -------------------------------------------------------------------------------
    def step(self) -> None:
        """One control period: goals -> ctrl (with the deadband) -> physics -> registers."""
        d = self.data
        q = d.qpos[self.cm.qpos_adr]
        ctrl = np.empty(self.n)
        for i, s in enumerate(self.table):
            g = min(max(self.goal_rad(i), s.min), s.max)
            ctrl[i] = q[i] if abs(g - q[i]) < self.deadband else g
        d.ctrl[self.cm.act_id] = ctrl
        mujoco.mj_step(self.model, d, nstep=self.substeps)
        self.time_us += self.period_us
        self.steps += 1
        self.stale = True  # present registers are refreshed when read (PlantBus calls refresh_if_stale)

    def refresh_if_stale(self) -> None:
        if self.stale:
            self.refresh()

    def refresh(self) -> None:
        """Present registers of every device from the current state."""
        self.stale = False
        d, cm = self.data, self.cm
        q = d.qpos[cm.qpos_adr]
        v = d.qvel[cm.dof_adr]
        f = d.actuator_force[cm.act_id]
        for i, s in enumerate(self.table):
            dev = self.servos[i]
            dev.set_u16(REG.PRESENT_POSITION, self._to_steps(i, float(q[i])))
            speed = int(round(s.direction * float(v[i]) / self.step_rad))
            dev.set_u16(REG.PRESENT_SPEED, to_sign_magnitude(max(-32767, min(32767, speed)), 15))
            load = int(round(s.direction * float(f[i]) / self.full[i] * 1000))
            dev.set_u16(REG.PRESENT_LOAD, to_sign_magnitude(max(-1000, min(1000, load)), 10))
            dev.table[REG.MOVING] = 1 if abs(speed) > 2 else 0
        pos, quat = cm.base_pose(d)
        rpy = quat_to_rpy(*quat)
        self.imu.table[56:62] = struct.pack("<3h", *(_q16(a) for a in rpy))
        objects = cm.objects
        n_top = toppled(d.qpos, objects) if objects else 0
        self.probe.table[56:86] = struct.pack("<7f2B", *pos, *quat, min(255, len(objects)), min(255, n_top))

    def fell(self) -> bool:
        w, x, y, z = self.cm.base_pose(self.data)[1]
        return 1 - 2 * (x * x + y * y) < math.cos(math.radians(60))
