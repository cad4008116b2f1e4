"""The plant's world: the robot's MuJoCo model driven by the servos' goal registers.

Per control period (one call of :meth:`World.step`): each servo's goal position (steps) becomes a
joint angle (``neutral + direction * (steps - centre) * step``), the servo's deadband holds it at
the measured position while the error is below the table's deadband (what the Python board's
servo model does per tick, here inside the servo where a real one does it), MuJoCo steps
``substeps`` times, and the present registers (position, speed, load), the IMU's roll/pitch/yaw
and the probe's ground truth are refreshed from the new state.

Conversions are the inverse of the C firmware's generated servo table
(:mod:`firmware_sim.cfirmware.servo_table`) and :mod:`robots.hardware`'s: raw position ``centre +
offset + sign * round((q - neutral) / step)`` with ``sign = direction * table_direction`` (offset 0
and direction +1 unless injected: :class:`~firmware_sim.plant.conditions.Conditions`), speed in
steps/s, load as a fraction of the servo's full torque.

The world holds one protocol-neutral :class:`~firmware_sim.plant.servo.ServoState` per servo
(:attr:`World.servos`, servo-table order); the wire protocols' control tables are views over them
(built by :class:`~firmware_sim.plant.bus.PlantBus`). A servo whose torque is off is limp: its
position actuator's gain and bias are zeroed until torque comes back on. A limp joint may be *held*
(:meth:`World.hold`, the plant's ``--hand``: a person's hand): it stays kinematically at that angle (position
set, velocity zero, every period) instead of sagging under gravity, until released or its torque comes on.
"""

from __future__ import annotations

import math
import struct

import mujoco
import numpy as np

from firmware_sim.board_reports import quat_to_rpy
from firmware_sim.servo_load import load_full_scale
from firmware_sim.plant.conditions import Conditions
from firmware_sim.plant.devices import STS_MODEL, ImuDevice, ProbeDevice
from firmware_sim.plant.servo import Fault, ServoState
from robots.description import Robot
from robots.hardware import STEP_CENTRE, ServoCalibration, step_limits
from robots.scenes import toppled

__all__ = ["LOW_VOLTAGE_DV", "World"]

#: what an undervolted servo reads (3.0 V: below the STS's and the XL330's minimum)
LOW_VOLTAGE_DV = 30


def _q16(v: float) -> int:
    return max(-32767, min(32767, int(round(v * 10_000))))


class World:
    """MuJoCo physics behind the bus devices (servo states 1..N, the IMU, the probe).

    ``conditions``: injected hardware conditions (offsets, reversal, model numbers, timed errors;
    the wire-side ones are read by the bus). ``model``: the model number every servo reports unless
    ``conditions.models`` says otherwise (None: the bus protocol's default, STS3215's 777 until a
    :class:`~firmware_sim.plant.bus.PlantBus` of another protocol sets it).
    """

    def __init__(self, robot: Robot, *, scene: str | None = None, rate_hz: int = 500, dt: float = 0.002,
                 conditions: Conditions | None = None, model: int | None = None) -> None:
        self.robot = robot
        self.table = robot.servos
        self.conditions = conditions or Conditions()
        self.model_number = model
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
        self._qpos_adr, self._dof_adr, self._act_id = self.cm.qpos_adr, self.cm.dof_adr, self.cm.act_id
        c = self.conditions
        self.servos: list[ServoState] = []
        # per servo: (neutral, sign, offset, joint min, joint max); sign = calibration direction * table direction
        self._consts: list[tuple[float, int, int, float, float]] = []
        for s in self.table:
            cal = ServoCalibration(s.id, c.offsets.get(s.id, 0), -1 if s.id in c.reversed else 1)
            lo, hi = step_limits(s, cal, self.step_rad)
            sign = cal.direction * s.direction
            self._consts.append((s.neutral, sign, cal.offset_steps, s.min, s.max))
            self.servos.append(ServoState(s.id, c.models.get(s.id, STS_MODEL if model is None else model), lo, hi, STEP_CENTRE))
        self.by_id = {st.id: st for st in self.servos}
        self.imu = ImuDevice()
        self.probe = ProbeDevice()
        self.time_us = 0
        self.steps = 0
        for i, s in enumerate(self.table):
            self.servos[i].goal_steps = self._to_steps(i, s.neutral)
        acts = list(self._act_id)
        self._gain0 = [float(self.model.actuator_gainprm[a, 0]) for a in acts]
        self._bias0 = [(float(self.model.actuator_biasprm[a, 1]), float(self.model.actuator_biasprm[a, 2])) for a in acts]
        self._driven = [True] * self.n
        #: servo index -> the joint angle (rad) a hand holds it at while its torque is off (:meth:`hold`)
        self.held: dict[int, float] = {}
        self._apply_conditions()
        self.stale = False
        self.refresh()

    # -- conversions ---------------------------------------------------------------------------
    def _to_steps(self, i: int, q: float) -> int:
        neutral, sign, offset, _, _ = self._consts[i]
        return max(0, min(4095, STEP_CENTRE + offset + sign * int(round((q - neutral) / self.step_rad))))

    def goal_rad(self, i: int) -> float:
        neutral, sign, offset, _, _ = self._consts[i]
        return neutral + sign * (self.servos[i].goal - STEP_CENTRE - offset) * self.step_rad

    def positions(self) -> np.ndarray:
        """Joint angles (rad), servo order, as MuJoCo has them."""
        return self.data.qpos[self.cm.qpos_adr].copy()

    # -- conditions and torque -----------------------------------------------------------------
    def _apply_conditions(self) -> None:
        """Timed hardware errors whose time has come: the fault bits, the reading that goes with them
        (temperature 85 C, above the limit; voltage :data:`LOW_VOLTAGE_DV`), torque off for the faults
        in the servo's shutdown set (:attr:`ServoState.shutdown`: overload and overheat by default)."""
        for e in self.conditions.errors:
            st = self.by_id.get(e.id)
            if st is None or self.time_us < e.at_us or st.fault & e.fault:
                continue
            st.fault |= e.fault
            if e.fault & Fault.OVERHEAT:
                st.temperature_c = 85
            if e.fault & Fault.VOLTAGE:
                st.voltage_dv = LOW_VOLTAGE_DV
            if e.fault & st.shutdown:
                st.torque = False

    def _sync_torque(self) -> None:
        """A servo with torque off is limp: its position actuator's gain and bias are zero."""
        m = self.model
        for i, st in enumerate(self.servos):
            if st.torque != self._driven[i]:
                a = self._act_id[i]
                m.actuator_gainprm[a, 0] = self._gain0[i] if st.torque else 0.0
                m.actuator_biasprm[a, 1], m.actuator_biasprm[a, 2] = self._bias0[i] if st.torque else (0.0, 0.0)
                self._driven[i] = st.torque

    # -- a hand --------------------------------------------------------------------------------
    def hold(self, i: int, q: float) -> float:
        """Hold servo ``i``'s joint at ``q`` (rad, held to the joint's range) while its torque is off, as a
        hand would (a servo with torque on drives itself: the hold waits until it is off). Applied now and
        after every period. Returns the angle held."""
        _, _, _, lo, hi = self._consts[i]
        q = min(max(float(q), lo), hi)
        self.held[i] = q
        self._apply_holds()
        mujoco.mj_forward(self.model, self.data)
        self.refresh()
        return q

    def release(self, i: int | None = None) -> None:
        """Let go of servo ``i``'s joint (None: of every joint): limp again, it sags under gravity."""
        if i is None:
            self.held.clear()
        else:
            self.held.pop(i, None)

    def _apply_holds(self) -> None:
        if not self.held:
            return
        d = self.data
        for i, q in self.held.items():
            if not self.servos[i].torque:
                d.qpos[self._qpos_adr[i]] = q
                d.qvel[self._dof_adr[i]] = 0.0

    # -- physics -------------------------------------------------------------------------------
    def step(self) -> None:
        """One control period: goals -> ctrl (with the deadband) -> physics -> registers.

        Per servo: ``steps`` is the goal held to the servo's limits (:attr:`ServoState.goal`);
        ``goal = clip(neutral + sign * (steps - centre - offset) * step, min, max)`` (rad, the joint's
        range) and ``ctrl = q`` while ``|goal - q| < deadband``. The loop runs over precomputed
        per-servo constants (~11 us a period for CoCo's 12 servos).
        """
        d = self.data
        self._sync_torque()
        q = d.qpos[self._qpos_adr].tolist()
        step, deadband = self.step_rad, self.deadband
        ctrl = []
        for st, (neutral, sign, offset, lo, hi), qi in zip(self.servos, self._consts, q):
            steps = max(st.min_steps, min(st.max_steps, st.goal_steps))
            g = min(max(neutral + sign * (steps - STEP_CENTRE - offset) * step, lo), hi)
            ctrl.append(qi if abs(g - qi) < deadband else g)
        d.ctrl[self._act_id] = ctrl
        self._apply_holds()
        mujoco.mj_step(self.model, d, nstep=self.substeps)
        self._apply_holds()
        self.time_us += self.period_us
        self.steps += 1
        self._apply_conditions()
        self.stale = True  # present values are refreshed when read (PlantBus calls refresh_if_stale)

    def refresh_if_stale(self) -> None:
        if self.stale:
            self.refresh()

    def refresh(self) -> None:
        """Present values of every servo state and the IMU's and probe's registers from the current state.

        Per servo: position ``centre + offset + sign * round((q - neutral) / step)`` steps (the STS
        register clips it to 0..4095); speed ``sign * qvel / step`` steps/s; load ``sign * force /
        full`` (fraction of full torque); moving while ``|round(speed)| > 2`` steps/s.
        """
        self.stale = False
        d, cm = self.data, self.cm
        step = self.step_rad
        q = d.qpos[self._qpos_adr].tolist()
        v = d.qvel[self._dof_adr].tolist()
        f = d.actuator_force[self._act_id].tolist()
        for st, (neutral, sign, offset, _, _), full, qi, vi, fi in zip(self.servos, self._consts, self.full, q, v, f):
            st.present_steps = STEP_CENTRE + offset + sign * round((qi - neutral) / step)
            st.speed_steps_s = sign * vi / step
            st.load = sign * fi / full
        pos, quat = cm.base_pose(d)
        rpy = quat_to_rpy(*quat)
        self.imu.table[56:62] = struct.pack("<3h", *(_q16(a) for a in rpy))
        objects = cm.objects
        n_top = toppled(d.qpos, objects) if objects else 0
        self.probe.table[56:86] = struct.pack("<7f2B", *pos, *quat, min(255, len(objects)), min(255, n_top))

    def fell(self) -> bool:
        w, x, y, z = self.cm.base_pose(self.data)[1]
        return 1 - 2 * (x * x + y * y) < math.cos(math.radians(60))
