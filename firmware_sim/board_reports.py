"""What a board reports of its model: TELEMETRY (servos and IMU) and SIM_STATE (the floating base, scene objects).

Held by :class:`firmware_sim.board.Board` (``board.reports``) over the board's compiled model and
``MjData`` for the board's life. The servos' joints, dofs and actuators are read as slices when they are
contiguous (:func:`as_slice`: cheaper than index arrays, per tick and per report). Units: positions
rad, velocities rad/s, efforts N*m, IMU roll/pitch/yaw rad (ZYX), base position m, quaternion w x y z.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import mujoco
import numpy as np

from protocol.messages import FaultFlags, Message, SimState, Telemetry
from robots.model import RobotModel
from robots.scenes import toppled

__all__ = ["BoardReports", "DeferredReports", "Snapshot", "as_slice", "quat_to_rpy"]


def as_slice(idx: np.ndarray) -> slice | np.ndarray:
    """``idx`` as an equivalent slice when it is a contiguous ascending run, else unchanged."""
    if len(idx) and np.array_equal(idx, np.arange(idx[0], idx[0] + len(idx))):
        return slice(int(idx[0]), int(idx[0]) + len(idx))
    return idx


def quat_to_rpy(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """Roll, pitch, yaw (rad, ZYX convention) of a unit quaternion."""
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


class BoardReports:
    """Reports of the world in ``data`` (of ``cm``'s model)."""

    def __init__(self, cm: RobotModel, data: mujoco.MjData) -> None:
        self.cm = cm
        self.data = data
        self.scene_objects = cm.objects
        #: the servos' joints (qpos), actuators (ctrl, actuator_force) and dofs (qvel): slices when contiguous
        self.qpos_at = as_slice(cm.qpos_adr)
        self.ctrl_at = as_slice(cm.act_id)
        self.dof_at = as_slice(cm.dof_adr)

    def telemetry(self, now_us: int, faults: FaultFlags, buffer_fill: int, last_applied_seq: int,
                  late_count: int, dropped_count: int, link_errors: int, snap: Snapshot | None = None) -> Telemetry:
        """TELEMETRY at board time ``now_us``: the servos and the IMU from the model (or from ``snap``, a
        :meth:`snapshot` of it), the rest as given."""
        d: mujoco.MjData | Snapshot = self.data if snap is None else snap
        w, x, y, z = (self.base_pose() if snap is None else snap.pose)[1]
        return Telemetry(
            board_time_us=now_us,
            positions=tuple(d.qpos[self.qpos_at].tolist()),
            velocities=tuple(d.qvel[self.dof_at].tolist()),
            efforts=tuple(d.actuator_force[self.ctrl_at].tolist()),
            imu_rpy=quat_to_rpy(w, x, y, z),
            faults=faults,
            buffer_fill=buffer_fill,
            last_applied_seq=last_applied_seq,
            late_count=late_count,
            dropped_count=dropped_count,
            link_errors=link_errors,
        )

    def base_pose(self) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """:meth:`robots.model.RobotModel.base_pose` (position m, quaternion w x y z), the floating base's
        seven qpos read in one slice (a report's hot spot: ~3 µs element by element)."""
        r = self.cm.root_qpos
        if r is None:
            return self.cm.base_pose(self.data)
        x, y, z, qw, qx, qy, qz = self.data.qpos[r:r + 7].tolist()
        return (x, y, z), (qw, qx, qy, qz)

    def sim_state(self, now_us: int, snap: Snapshot | None = None) -> SimState:
        """SIM_STATE at board time ``now_us``: ground truth of the floating base (emulator only), from the
        model or from ``snap``."""
        pos, quat = self.base_pose() if snap is None else snap.pose
        qpos = self.data.qpos if snap is None else snap.qpos
        return SimState(
            now_us, pos, quat,
            objects=len(self.scene_objects),
            toppled=toppled(qpos, self.scene_objects) if self.scene_objects else 0,
        )

    def snapshot(self) -> Snapshot:
        """What :meth:`telemetry` and :meth:`sim_state` read of the model, copied now (~2 us), so the
        reports can be built later, while the model moves on (the lockstep server builds them while the
        next ticks run: :class:`DeferredReports`)."""
        d = self.data
        return Snapshot(d.qpos.copy(), d.qvel.copy(), d.actuator_force.copy(), self.base_pose())


    def snapshot_regions(self) -> tuple[int, list[tuple[int, int, int]]]:
        """What :meth:`snapshot` copies, as regions of one float64 buffer for the C to fill
        (:meth:`firmware_sim.native.NativeTick.run_split_during`): (buffer length, [(offset in the buffer,
        source address in ``MjData``, doubles)]): qpos, qvel, actuator_force, and for a fixed base the root
        body's xpos and xquat. :meth:`snapshot_of` reads such a buffer. The addresses hold for ``data``'s life."""
        d = self.data
        regions: list[tuple[int, int, int]] = []
        off = 0
        for a in (d.qpos, d.qvel, d.actuator_force):
            regions.append((off, int(a.__array_interface__["data"][0]), a.size))
            off += a.size
        if self.cm.root_qpos is None:
            b = self.cm.root_body
            for a, k in ((d.xpos, 3), (d.xquat, 4)):
                regions.append((off, int(a.__array_interface__["data"][0]) + 8 * k * b, k))
                off += k
        return off, regions

    def snapshot_of(self, buf: np.ndarray) -> Snapshot:
        """The :class:`Snapshot` in ``buf``, filled by the regions of :meth:`snapshot_regions` (views into it)."""
        d = self.data
        nq, nv, nu = d.qpos.size, d.qvel.size, d.actuator_force.size
        qpos = buf[:nq]
        r = self.cm.root_qpos
        if r is not None:
            x, y, z, qw, qx, qy, qz = qpos[r:r + 7].tolist()
        else:
            x, y, z, qw, qx, qy, qz = buf[nq + nv + nu:nq + nv + nu + 7].tolist()
        return Snapshot(qpos, buf[nq:nq + nv], buf[nq + nv:nq + nv + nu], ((x, y, z), (qw, qx, qy, qz)))


class Snapshot(NamedTuple):
    """The parts of ``MjData`` a report reads (copies), and the base pose (position m, quaternion w x y z)."""

    qpos: np.ndarray
    qvel: np.ndarray
    actuator_force: np.ndarray
    pose: tuple[tuple[float, float, float], tuple[float, float, float, float]]


class DeferredReports:
    """A report period's TELEMETRY and SIM_STATE, to be built by :meth:`messages`: the board's counters
    as they were (taken, the since-last-report flags cleared, when this was made) and a :class:`Snapshot`
    of the model. What :meth:`firmware_sim.board.Board.run` returns in their place when the board's
    ``defer_reports`` is set (the lockstep server's overlap, :mod:`firmware_sim.server`)."""

    __slots__ = ("reports", "now_us", "counters", "snap")

    def __init__(self, reports: BoardReports, now_us: int, counters: tuple[FaultFlags, int, int, int, int, int],
                 snap: Snapshot) -> None:
        self.reports, self.now_us, self.counters, self.snap = reports, now_us, counters, snap

    def messages(self) -> list[Message]:
        """[TELEMETRY, SIM_STATE], as :meth:`firmware_sim.board.Board.telemetry` and ``sim_state`` would
        have made them when this was made."""
        r = self.reports
        return [r.telemetry(self.now_us, *self.counters, snap=self.snap), r.sim_state(self.now_us, self.snap)]
