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


#: registers 9..43 of a servo as one block: min angle, max angle, (29 bytes), goal position
_GOAL_LO, _GOAL_HI = REG.MIN_ANGLE, REG.GOAL_POSITION + 2
_GOAL_FMT = f"HH{REG.GOAL_POSITION - REG.MIN_ANGLE - 4}xH"
assert REG.MAX_ANGLE == REG.MIN_ANGLE + 2 < REG.GOAL_POSITION, "the goal block reads min, max, ..., goal"
#: present position, speed and load (registers 56..61)
_PRESENT = struct.Struct("<3H")


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
        # per-servo constants, servo order (step() and refresh() run every control period)
        self._goal_consts = [(s.neutral, s.direction, s.min, s.max) for s in self.table]
        self._goal_block = struct.Struct("<" + _GOAL_FMT * self.n)
        self._qpos_adr, self._dof_adr, self._act_id = self.cm.qpos_adr, self.cm.dof_adr, self.cm.act_id
        self.servos: list[ServoDevice] = []
        for s in self.table:
            lo, hi = _step_range(s.neutral, s.min, s.max, s.direction, self.step_rad)
            self.servos.append(ServoDevice(s.id, lo, hi, STEP_CENTRE))
        self._present_consts = list(zip(self.servos, [s.neutral for s in self.table],
                                        [s.direction for s in self.table], self.full))
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
        """One control period: goals -> ctrl (with the deadband) -> physics -> registers.

        Per servo: ``steps`` is the goal position register (sign-magnitude at bit 15) held to the
        angle-limit registers 9..12 (:attr:`ServoDevice.goal`); ``goal = clip(neutral + direction *
        (steps - centre) * step, min, max)`` (rad, the joint's range) and ``ctrl = q`` while
        ``|goal - q| < deadband``. The goal registers of all servos are read in one
        ``struct`` call and the loop runs over precomputed per-servo constants (~11 us a period for
        CoCo's 12 servos; numpy's per-call overhead made a vectorised form slower at this size).
        """
        d = self.data
        regs = self._goal_block.unpack(b"".join([dev.table[_GOAL_LO:_GOAL_HI] for dev in self.servos]))
        q = d.qpos[self._qpos_adr].tolist()
        step, deadband = self.step_rad, self.deadband
        ctrl = []
        for i, (neutral, direction, lo, hi) in enumerate(self._goal_consts):
            lim_lo, lim_hi, raw = regs[3 * i:3 * i + 3]
            steps = max(lim_lo, min(lim_hi, -(raw & 0x7FFF) if raw & 0x8000 else raw))  # ServoDevice.goal
            g = min(max(neutral + direction * (steps - STEP_CENTRE) * step, lo), hi)
            qi = q[i]
            ctrl.append(qi if abs(g - qi) < deadband else g)
        d.ctrl[self._act_id] = ctrl
        mujoco.mj_step(self.model, d, nstep=self.substeps)
        self.time_us += self.period_us
        self.steps += 1
        self.stale = True  # present registers are refreshed when read (PlantBus calls refresh_if_stale)

    def refresh_if_stale(self) -> None:
        if self.stale:
            self.refresh()

    def refresh(self) -> None:
        """Present registers of every device from the current state.

        Per servo: position ``clip(centre + direction * round((q - neutral) / step), 0, 4095)``
        steps; speed ``round(direction * qvel / step)`` steps/s held to +-32767, sign-magnitude at bit
        15; load ``round(direction * force / full * 1000)`` (0.1 % of full torque) held to +-1000,
        sign-magnitude at bit 10;
        moving while ``|speed| > 2`` steps/s.
        """
        self.stale = False
        d, cm = self.data, self.cm
        step = self.step_rad
        q = d.qpos[self._qpos_adr].tolist()
        v = d.qvel[self._dof_adr].tolist()
        f = d.actuator_force[self._act_id].tolist()
        for (dev, neutral, direction, full), qi, vi, fi in zip(self._present_consts, q, v, f):
            pos = max(0, min(4095, STEP_CENTRE + direction * round((qi - neutral) / step)))
            speed = round(direction * vi / step)
            load = round(direction * fi / full * 1000)
            _PRESENT.pack_into(dev.table, REG.PRESENT_POSITION, pos, to_sign_magnitude(max(-32767, min(32767, speed)), 15),
                               to_sign_magnitude(max(-1000, min(1000, load)), 10))
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
