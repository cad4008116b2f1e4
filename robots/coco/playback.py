"""Play motions on CoCo in MuJoCo the way the board does, and measure what the base did.

Used by the gait calibration (``robots/coco/calibrate_gaits.py``) and the motion tests. Like the board,
targets are interpolated at the control rate (500 Hz, one 2 ms physics step per tick), clamped to
the joint limits and speed limits, quantised to the encoder resolution, and held inside the
deadband. This mirrors ``firmware_sim``'s servo model in a few lines because ``robots`` may not
import ``firmware_sim``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from robots.coco import load_poses
from robots.coco.model import CocoModel, load_model
from robots.coco.trajectory import Motion

__all__ = ["Measurement", "Player"]

CONTROL_RATE_HZ = 500


@dataclass(frozen=True)
class Measurement:
    """What the base did while motions played (relative to where it started)."""

    forward_cm: float  # along the starting heading
    left_cm: float  # perpendicular, + = to the robot's left
    yaw_deg: float  # unwrapped, + = counter-clockwise
    max_tilt_deg: float
    min_height_cm: float  # lowest torso-centre height
    duration_s: float


class Player:
    """A CoCo in MuJoCo standing in ``pose``; :meth:`play` runs motions from the current targets."""

    def __init__(self, pose: str = "stand", settle_s: float = 0.3) -> None:
        self.cm: CocoModel = load_model()
        self.model = self.cm.model
        self.data = self.cm.new_data()
        steps = 1.0 / (CONTROL_RATE_HZ * self.model.opt.timestep)
        if abs(steps - round(steps)) > 1e-6 or round(steps) < 1:
            raise ValueError(f"MJCF timestep {self.model.opt.timestep} does not divide the {CONTROL_RATE_HZ} Hz tick")
        self.substeps = round(steps)
        self._torso = self.model.body("torso").id
        table = self.cm.table
        self.lo, self.hi = np.array(table.mins), np.array(table.maxs)
        self.vmax = np.array(table.max_speeds)
        self.resolution, self.deadband = table.model.resolution, table.model.deadband
        self.targets = np.array(load_poses()[pose], dtype=float)
        self.cmd = self.targets.copy()
        self.cm.place_on_floor(self.data, self.targets)
        self.time = 0.0
        self._run(np.repeat(self.targets[None, :], max(1, round(settle_s * CONTROL_RATE_HZ)), axis=0))

    # --- state -------------------------------------------------------------------------------
    def base(self) -> tuple[np.ndarray, float]:
        """Torso position (m) and yaw (rad)."""
        w, x, y, z = self.data.qpos[3:7]
        return self.data.qpos[0:3].copy(), math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))

    def tilt_deg(self) -> float:
        r22 = float(self.data.xmat[self._torso].reshape(3, 3)[2, 2])
        return math.degrees(math.acos(min(1.0, max(-1.0, r22))))

    # --- playing -----------------------------------------------------------------------------
    def play(self, motions: Motion | Sequence[Motion], hold_s: float = 0.3, loops: float = 0.0) -> Measurement:
        """Play ``motions`` one after the other (each from the targets the previous one left), then hold.

        ``loops`` plays that many extra passes of a looping motion's cycle.
        """
        if isinstance(motions, Motion):
            motions = [motions]
        rows = []
        for m in motions:
            idx = list(m.servos)
            if not np.allclose(m.q[0], self.targets[idx], atol=1e-9):
                raise ValueError("motion does not start at the current targets")
            end = m.t[-1]
            if m.loop_from is not None and loops > 0:
                end += loops * (m.t[-1] - m.loop_from)
            tick = np.arange(1, math.floor(end * CONTROL_RATE_HZ + 1e-9) + 1) / CONTROL_RATE_HZ
            if len(tick) == 0 or tick[-1] < end - 1e-9:
                tick = np.append(tick, end)
            q = np.repeat(self.targets[None, :], len(tick), axis=0)
            q[:, idx] = m.at(tick)
            self.targets = q[-1].copy()
            rows.append(q)
        rows.append(np.repeat(self.targets[None, :], max(1, round(hold_s * CONTROL_RATE_HZ)), axis=0))
        return self._run(np.concatenate(rows))

    def _run(self, desired: np.ndarray) -> Measurement:
        d, m = self.data, self.model
        p0, yaw0 = self.base()
        yaw_prev, yaw_acc = yaw0, 0.0
        max_tilt, min_z = 0.0, float(p0[2])
        act, qadr = self.cm.act_id, self.cm.qpos_adr
        step_max = self.vmax / CONTROL_RATE_HZ
        for row in desired:
            target = np.clip(row, self.lo, self.hi)
            self.cmd = self.cmd + np.clip(target - self.cmd, -step_max, step_max)
            quant = np.clip(np.round(self.cmd / self.resolution) * self.resolution, self.lo, self.hi)
            measured = d.qpos[qadr]
            d.ctrl[act] = np.where(np.abs(quant - measured) < self.deadband, measured, quant)
            for _ in range(self.substeps):
                mujoco.mj_step(m, d)
            _, yaw = self.base()
            yaw_acc += (yaw - yaw_prev + math.pi) % (2 * math.pi) - math.pi
            yaw_prev = yaw
            max_tilt = max(max_tilt, self.tilt_deg())
            min_z = min(min_z, float(d.qpos[2]))
        self.time += len(desired) / CONTROL_RATE_HZ
        p1, _ = self.base()
        dx, dy = p1[0] - p0[0], p1[1] - p0[1]
        c, s = math.cos(yaw0), math.sin(yaw0)
        return Measurement(
            forward_cm=100 * (c * dx + s * dy),
            left_cm=100 * (-s * dx + c * dy),
            yaw_deg=math.degrees(yaw_acc),
            max_tilt_deg=max_tilt,
            min_height_cm=100 * min_z,
            duration_s=len(desired) / CONTROL_RATE_HZ,
        )
