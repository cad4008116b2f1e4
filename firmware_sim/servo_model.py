"""Hobby smart-servo model applied to every target before it becomes MuJoCo ctrl.

Per tick and per servo, in this order: clamp to the joint limits, clamp the
change since the last command to the speed limit, quantise to the encoder
resolution, then the deadband (no drive while the position error is smaller
than the deadband: ctrl is set to the measured position). Clamps are reported
so the board can flag CLAMPED in telemetry.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["ServoModel"]

_EPS = 1e-9


class ServoModel:
    """Vectorised over all servos; ``cmd`` is the last speed-limited command (before quantisation)."""

    def __init__(
        self,
        mins: Sequence[float],
        maxs: Sequence[float],
        max_speeds: Sequence[float],
        resolution: float,
        deadband: float,
        period_s: float,
    ) -> None:
        self.mins = np.asarray(mins, dtype=float)
        self.maxs = np.asarray(maxs, dtype=float)
        self.max_speeds = np.asarray(max_speeds, dtype=float)
        self.resolution = float(resolution)
        self.deadband = float(deadband)
        self.period_s = float(period_s)
        self.cmd = np.clip(np.zeros_like(self.mins), self.mins, self.maxs)
        self.limit_clamps = 0  # servo-ticks clamped to a joint limit, since boot
        self.speed_clamps = 0  # servo-ticks clamped to the speed limit, since boot

    def reset(self, q: Sequence[float] | np.ndarray) -> None:
        """Set the command to ``q`` (clamped to limits) without speed limiting."""
        self.cmd = np.clip(np.asarray(q, dtype=float), self.mins, self.maxs)

    def quantise(self, q: np.ndarray) -> np.ndarray:
        return np.clip(np.round(q / self.resolution) * self.resolution, self.mins, self.maxs)

    def step(
        self, desired: np.ndarray, measured: np.ndarray, speed_cap: float | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Return (ctrl, clamped mask) for one tick; ``speed_cap`` lowers every speed limit (rad/s)."""
        target = np.clip(desired, self.mins, self.maxs)
        limit_hit = np.abs(target - desired) > _EPS
        speeds = self.max_speeds if speed_cap is None else np.minimum(self.max_speeds, speed_cap)
        max_step = speeds * self.period_s
        delta = target - self.cmd
        speed_hit = np.abs(delta) > max_step + _EPS
        self.cmd = self.cmd + np.clip(delta, -max_step, max_step)
        q = self.quantise(self.cmd)
        ctrl = np.where(np.abs(q - measured) < self.deadband, measured, q)
        ctrl = np.clip(ctrl, self.mins, self.maxs)
        self.limit_clamps += int(limit_hit.sum())
        self.speed_clamps += int(speed_hit.sum())
        return ctrl, limit_hit | speed_hit
