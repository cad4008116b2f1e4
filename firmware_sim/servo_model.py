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
bit-identical. :meth:`ServoModel.step` keeps the array interface. The board normally runs the
same arithmetic in C (:mod:`firmware_sim.native`, on this model's ``_cmd`` array and its table
arrays); this module stays the reference the C is tested against, and runs when the C cannot.
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
        self.max_step = self.max_speeds * self.period_s  # rad per tick at the table speeds
        self._max_step = self.max_step.tolist()
        #: the command, in place for the life of the model (the native tick holds its address)
        self._cmd: np.ndarray = np.clip(np.zeros_like(self.mins), self.mins, self.maxs)
        self._limit_clamps = 0
        self._speed_clamps = 0
        #: counts kept by the native tick (``limit_clamps``/``speed_clamps``), added to the Python path's
        self.native_counts: object | None = None

    @property
    def limit_clamps(self) -> int:
        """Servo-ticks clamped to a joint limit, since boot."""
        return self._limit_clamps + (self.native_counts.limit_clamps if self.native_counts is not None else 0)  # type: ignore[attr-defined]

    @property
    def speed_clamps(self) -> int:
        """Servo-ticks clamped to the speed limit, since boot."""
        return self._speed_clamps + (self.native_counts.speed_clamps if self.native_counts is not None else 0)  # type: ignore[attr-defined]

    @property
    def cmd(self) -> np.ndarray:
        """The last speed-limited command per servo (rad), a new array."""
        return self._cmd.copy()

    def cmd_of(self, i: int) -> float:
        return float(self._cmd[i])

    def reset(self, q: Sequence[float] | np.ndarray) -> None:
        """Set the command to ``q`` (clamped to limits) without speed limiting."""
        self._cmd[:] = np.clip(np.asarray(q, dtype=float), self.mins, self.maxs)

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
        mins, maxs, cmd = self._mins, self._maxs, self._cmd.tolist()
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
        self._cmd[:] = cmd
        self._limit_clamps += limit_hits
        self._speed_clamps += speed_hits
        return ctrl, (hits if mask else bool(limit_hits or speed_hits))
