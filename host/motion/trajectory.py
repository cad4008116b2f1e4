"""Minimum-jerk point-to-point trajectories for the servo vector (numpy).

``q(s) = q0 + (q1 - q0) * (10 s^3 - 15 s^4 + 6 s^5)`` with ``s = t / T``: zero
velocity and acceleration at both ends; the peak speed is ``1.875 |dq| / T``, so a
servo's speed limit ``v`` needs ``T >= 1.875 |dq| / v``. :func:`min_jerk` stretches
the requested duration to the slowest servo's need.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["PEAK_SPEED_FACTOR", "min_jerk", "min_jerk_duration", "min_jerk_profile"]

#: max over s of d/ds (10 s^3 - 15 s^4 + 6 s^5), reached at s = 1/2
PEAK_SPEED_FACTOR = 1.875


def min_jerk_profile(s: np.ndarray) -> np.ndarray:
    """Normalised position profile on ``s`` in [0, 1] (clipped outside)."""
    s = np.clip(np.asarray(s, dtype=float), 0.0, 1.0)
    return s**3 * (10.0 + s * (-15.0 + 6.0 * s))


def min_jerk_duration(
    q0: Sequence[float] | np.ndarray,
    q1: Sequence[float] | np.ndarray,
    duration: float,
    max_speed: Sequence[float] | np.ndarray | None = None,
) -> float:
    """``duration`` stretched so no servo's peak speed exceeds its ``max_speed`` (rad/s)."""
    if not duration >= 0.0:
        raise ValueError(f"duration must be >= 0 s, got {duration}")
    dq = np.abs(np.asarray(q1, dtype=float) - np.asarray(q0, dtype=float))
    if max_speed is None:
        return float(duration)
    v = np.asarray(max_speed, dtype=float)
    if v.shape != dq.shape or np.any(v <= 0):
        raise ValueError("max_speed needs one positive value per servo")
    return float(max(duration, float(np.max(PEAK_SPEED_FACTOR * dq / v)) if dq.size else 0.0))


def _default_speeds(n: int) -> tuple[float, ...] | None:
    from robots.coco import load_servo_table

    table = load_servo_table()
    return table.max_speeds if n == len(table) else None


def min_jerk(
    q0: Sequence[float] | np.ndarray,
    q1: Sequence[float] | np.ndarray,
    duration: float,
    rate_hz: float,
    max_speed: Sequence[float] | np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Sample a min-jerk move from ``q0`` to ``q1``.

    Returns ``(times, positions)``: times in seconds from 0 to the (possibly stretched)
    duration at ``1 / rate_hz`` steps, the last sample exactly at the end; positions has
    shape ``(len(times), n)`` and ends exactly at ``q1``. ``max_speed`` (rad/s per servo)
    stretches the duration so no servo is asked for more than its speed; when omitted
    for a vector of CoCo's servo count, the servo table's speeds are used.
    """
    a = np.asarray(q0, dtype=float)
    b = np.asarray(q1, dtype=float)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"q0 and q1 must be 1-D of equal length, got {a.shape} and {b.shape}")
    if not rate_hz > 0:
        raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
    if max_speed is None:
        max_speed = _default_speeds(a.size)
    T = min_jerk_duration(a, b, duration, max_speed)
    step = 1.0 / rate_hz
    n = int(np.ceil(T / step - 1e-9))
    times = np.minimum(np.arange(n + 1) * step, T) if n > 0 else np.array([0.0])
    if n > 0:
        times[-1] = T
    s = times / T if T > 0 else np.ones_like(times)
    positions = a + np.outer(min_jerk_profile(s), b - a)
    positions[-1] = b
    return times, positions
