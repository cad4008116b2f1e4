"""Hobby smart-servo model applied to every target before it becomes MuJoCo ctrl.

Per tick and per servo, in this order: clamp to the joint limits, clamp the
change since the last command to the speed limit, quantise to the encoder
resolution, then the deadband (no drive while the position error is smaller
than the deadband: ctrl is set to the measured position). Clamps are reported
so the board can flag CLAMPED in telemetry.

:meth:`ServoModel.step_list` is the per-tick hot path of the board: a plain
Python loop over the 12 servos' floats. For 12 elements that is about three
times faster than the ~20 numpy ufunc calls of the vectorised form (each call
costs ~0.5-1 µs of overhead), and it does the same IEEE double operations in the
same order (``round`` is round-half-even like ``np.round``), so results are
bit-identical. :meth:`ServoModel.step` keeps the array interface.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["ServoModel"]

_EPS = 1e-9


class ServoModel:
    """All servos of a board; ``cmd`` is the last speed-limited command (before quantisation)."""

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
        self._mins = self.mins.tolist()
        self._maxs = self.maxs.tolist()
        self._max_step = (self.max_speeds * self.period_s).tolist()  # rad per tick at the table speeds
        self._cmd: list[float] = np.clip(np.zeros_like(self.mins), self.mins, self.maxs).tolist()
        self.limit_clamps = 0  # servo-ticks clamped to a joint limit, since boot
        self.speed_clamps = 0  # servo-ticks clamped to the speed limit, since boot

    @property
    def cmd(self) -> np.ndarray:
        """The last speed-limited command per servo (rad), a new array."""
        return np.array(self._cmd)

    def cmd_of(self, i: int) -> float:
        return self._cmd[i]

    def reset(self, q: Sequence[float] | np.ndarray) -> None:
        """Set the command to ``q`` (clamped to limits) without speed limiting."""
        self._cmd = np.clip(np.asarray(q, dtype=float), self.mins, self.maxs).tolist()

    def quantise(self, q: np.ndarray) -> np.ndarray:
        return np.clip(np.round(q / self.resolution) * self.resolution, self.mins, self.maxs)

    def step(
        self, desired: np.ndarray, measured: np.ndarray, speed_cap: float | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Return (ctrl, clamped mask) for one tick; ``speed_cap`` lowers every speed limit (rad/s)."""
        ctrl, clamped = self.step_list(list(map(float, desired)), list(map(float, measured)), speed_cap, mask=True)
        return np.array(ctrl), np.array(clamped, dtype=bool)

    def step_list(self, desired: Sequence[float], measured: Sequence[float], speed_cap: float | None = None,
                  mask: bool = False) -> tuple[list[float], list[bool] | bool]:
        """:meth:`step` on plain float sequences: (ctrl list, any servo clamped) — or, with ``mask``,
        the per-servo clamped list."""
        mins, maxs, cmd = self._mins, self._maxs, self._cmd
        steps = self._max_step if speed_cap is None else [
            min(s, speed_cap) * self.period_s for s in self.max_speeds.tolist()]
        res, db = self.resolution, self.deadband
        ctrl = [0.0] * len(cmd)
        hits: list[bool] = [False] * len(cmd)
        limit_hits = speed_hits = 0
        for i in range(len(cmd)):
            x, lo, hi = desired[i], mins[i], maxs[i]
            tg = hi if x > hi else (lo if x < lo else x)
            hit = False
            if abs(tg - x) > _EPS:
                limit_hits += 1
                hit = True
            c = cmd[i]
            delta, s = tg - c, steps[i]
            if abs(delta) > s + _EPS:
                speed_hits += 1
                hit = True
            c += s if delta > s else (-s if delta < -s else delta)
            cmd[i] = c
            q = round(c / res) * res
            q = hi if q > hi else (lo if q < lo else q)
            m = measured[i]
            v = m if abs(q - m) < db else q
            ctrl[i] = hi if v > hi else (lo if v < lo else v)
            hits[i] = hit
        self.limit_clamps += limit_hits
        self.speed_clamps += speed_hits
        return ctrl, (hits if mask else bool(limit_hits or speed_hits))
