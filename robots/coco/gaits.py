"""Gaits for CoCo's 2-DOF legs: a diagonal trot that walks, turns in place, crab-walks and creeps.

Each leg has a hip that swings the foot about the vertical axis (+ = forward) and a knee that lifts
it. Diagonal pairs (front-right + back-left, front-left + back-right) alternate: while one pair
swings through the air (knee lifted, hip moving against the stance direction) the other pushes on
the ground. A *pattern* gives each leg's stance sweep sign (legs front-right, front-left, back-left,
back-right); walking, turning and sidestepping are three orthogonal patterns because the legs
stand at 45 degrees:

    forward  (-1, -1, -1, -1)     turn left (-1, +1, +1, -1)     right (+1, -1, +1, -1)

The amplitude fades in over the first half cycle and out over the last, so a gait starts and ends
in the stand pose. Distance and angle per cycle come from MuJoCo: ``gait.toml`` next to this file,
written by ``robots/coco/calibrate_gaits.py``.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, replace
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from robots.coco import LEG_NAMES, load_poses, load_servo_table
from robots.coco.trajectory import (
    CHANNEL_SERVOS,
    DT,
    Motion,
    Track,
    check_choice,
    check_count,
    check_finite,
    check_start,
    min_jerk,
)

__all__ = [
    "CALIBRATION_PATH",
    "FORWARD",
    "GaitParams",
    "RIGHT",
    "TURN_LEFT",
    "creep",
    "gait_motion",
    "gait_targets",
    "load_calibration",
    "move_strides",
    "plan_rotate",
    "plan_walk",
    "rotate",
    "run_distance",
    "walk_params",
]

CALIBRATION_PATH: Path = Path(__file__).resolve().parent / "gait.toml"

FORWARD = np.array([-1.0, -1.0, -1.0, -1.0])
TURN_LEFT = np.array([-1.0, 1.0, 1.0, -1.0])
RIGHT = np.array([1.0, -1.0, 1.0, -1.0])
#: Phase offset of legs front-right, front-left, back-left, back-right (diagonal pairs).
PHASE = np.array([0.0, 0.5, 0.0, 0.5])
#: Posture speed for getting into the gait's base pose (rad/s).
POSTURE_SPEED = math.radians(150.0)
TURN_PERIOD = 0.7
TURN_AMPLITUDE_DEG = 20.0


def _body_columns() -> tuple[np.ndarray, np.ndarray]:
    """Positions of each leg's hip and knee inside the body channel (legs 1..4)."""
    table = load_servo_table()
    body = list(CHANNEL_SERVOS["body"])
    hips = [body.index(table.by_name(f"{LEG_NAMES[leg]}_hip").index) for leg in (1, 2, 3, 4)]
    knees = [body.index(table.by_name(f"{LEG_NAMES[leg]}_knee").index) for leg in (1, 2, 3, 4)]
    return np.array(hips), np.array(knees)


HIP_COLS, KNEE_COLS = _body_columns()


def stand_body() -> np.ndarray:
    """The stand pose of the body channel (radians)."""
    return np.array(load_poses()["stand"])[list(CHANNEL_SERVOS["body"])]


@dataclass(frozen=True)
class GaitParams:
    """One gait: cycle period (s), hip amplitude and knee lift (rad), base pose, stance pattern."""

    period: float
    amplitude: float
    lift: float
    pattern: np.ndarray
    base: np.ndarray


def walk_params(speed: float = 50, amplitude: float = 50) -> tuple[float, float]:
    """(period s, hip amplitude deg) of the walking gait for speed and amplitude in 0..100."""
    s = min(max(float(speed), 0.0), 100.0) / 100.0
    a = min(max(float(amplitude), 0.0), 100.0) / 100.0
    return 0.9 - 0.4 * s, 10.0 + 12.0 * a


def gait_targets(t: np.ndarray, p: GaitParams, cycles: float, ramp_out: bool = True) -> np.ndarray:
    """Body-channel targets (len(t), 8) of ``cycles`` gait cycles at times ``t`` (s)."""
    t = np.asarray(t, dtype=float)[:, None]
    half = p.period / 2.0
    env = min_jerk(t / half)
    if ramp_out:
        env = env * (1.0 - min_jerk((t - (cycles * p.period - half)) / half))
    phase = np.mod(t / p.period + PHASE[None, :], 1.0)
    q = np.repeat(p.base[None, :], len(t), axis=0)
    q[:, HIP_COLS] += p.amplitude * p.pattern[None, :] * env * np.cos(2.0 * np.pi * phase)
    swing = np.where(phase < 0.5, np.sin(2.0 * np.pi * phase) ** 2, 0.0)
    q[:, KNEE_COLS] += p.lift * swing
    return q


def gait_motion(start: np.ndarray, p: GaitParams, cycles: int, persistent: bool = False) -> Motion:
    """Move to the gait's base pose, then walk ``cycles`` cycles (or loop when ``persistent``)."""
    start = check_start(start)
    track = Track(CHANNEL_SERVOS["body"], start).move(p.base, speed=POSTURE_SPEED)
    n = max(2, round(p.period / DT))
    dt = p.period / n
    if persistent:
        t = np.arange(1, n + 1) * dt
        track.samples(dt, gait_targets(t, p, 1.0, ramp_out=False))
        track.mark_loop()
        one = gait_targets(p.period + t, p, 1.0, ramp_out=False)
        one[-1] = track.q  # exact seam
        track.samples(dt, one)
    elif cycles > 0:
        t = np.arange(1, cycles * n + 1) * dt
        q = gait_targets(t, p, cycles)
        q[-1] = p.base
        track.samples(dt, q)
    return track.build()


# --- calibration ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Calibration:
    """Measured travel per cycle: ``travel = offset + per_cycle * cycles`` (cm or degrees)."""

    speeds: np.ndarray
    amplitudes: np.ndarray
    forward_per_cycle: np.ndarray  # (speeds, amplitudes) cm
    forward_offset: np.ndarray
    backward_per_cycle: np.ndarray
    backward_offset: np.ndarray
    forward_trim: float  # turn-pattern weight that cancels walking yaw drift
    backward_trim: float
    left_per_cycle: float  # degrees
    left_offset: float
    right_per_cycle: float
    right_offset: float


_DEFAULT = {
    "walk": {
        "speeds": [0, 50, 100], "amplitudes": [0, 50, 100],
        "forward_per_cycle": [[4.0] * 3] * 3, "forward_offset": [[0.0] * 3] * 3,
        "backward_per_cycle": [[4.0] * 3] * 3, "backward_offset": [[0.0] * 3] * 3,
        "forward_trim": 0.0, "backward_trim": 0.0,
    },
    "turn": {"left_per_cycle": 30.0, "left_offset": 0.0, "right_per_cycle": 30.0, "right_offset": 0.0},
}


@cache
def load_calibration(path: Path | None = None) -> Calibration:
    """Read ``gait.toml`` (falls back to rough defaults if it is missing)."""
    p = Path(path) if path is not None else CALIBRATION_PATH
    data: dict[str, Any] = tomllib.loads(p.read_text()) if p.exists() else _DEFAULT
    w, r = data["walk"], data["turn"]

    def arr(k: str) -> np.ndarray:
        return np.array(w[k], dtype=float)

    return Calibration(
        arr("speeds"), arr("amplitudes"), arr("forward_per_cycle"), arr("forward_offset"),
        arr("backward_per_cycle"), arr("backward_offset"), float(w["forward_trim"]),
        float(w["backward_trim"]), float(r["left_per_cycle"]), float(r["left_offset"]),
        float(r["right_per_cycle"]), float(r["right_offset"]),
    )


def _bilinear(xs: np.ndarray, ys: np.ndarray, grid: np.ndarray, x: float, y: float) -> float:
    rows = np.array([np.interp(y, ys, grid[i]) for i in range(len(xs))])
    return float(np.interp(x, xs, rows))


def _cycles_for(target: float, offset: float, per_cycle: float) -> tuple[int, float]:
    """Whole cycles and amplitude scale (<= 1) so that ``scale * (offset + per_cycle * n) == target``."""
    per_cycle = max(per_cycle, 1e-6)
    n = max(1, math.ceil((target - offset) / per_cycle - 1e-9))
    reach = offset + per_cycle * n
    return n, (min(1.0, target / reach) if reach > 0 else 1.0)


def plan_walk(distance: float, speed: float = 50, amplitude: float = 50,
              cal: Calibration | None = None) -> tuple[GaitParams, int]:
    """Gait and cycle count that walk ``distance`` cm (negative: backwards)."""
    cal = cal or load_calibration()
    period, amp_deg = walk_params(speed, amplitude)
    sign = 1.0 if distance >= 0 else -1.0
    key = "forward" if sign > 0 else "backward"
    per = _bilinear(cal.speeds, cal.amplitudes, getattr(cal, f"{key}_per_cycle"), speed, amplitude)
    off = _bilinear(cal.speeds, cal.amplitudes, getattr(cal, f"{key}_offset"), speed, amplitude)
    trim = getattr(cal, f"{key}_trim")
    n, scale = _cycles_for(abs(distance), off, per)
    pattern = sign * FORWARD + trim * TURN_LEFT
    return GaitParams(period, math.radians(amp_deg) * scale, math.radians(25.0), pattern, stand_body()), n


def plan_rotate(angle: float, cal: Calibration | None = None) -> tuple[GaitParams, int]:
    """Gait and cycle count that turn ``angle`` degrees in place (positive: left / CCW)."""
    cal = cal or load_calibration()
    sign = 1.0 if angle >= 0 else -1.0
    per, off = (cal.left_per_cycle, cal.left_offset) if sign > 0 else (cal.right_per_cycle, cal.right_offset)
    n, scale = _cycles_for(abs(angle), off, per)
    amp = math.radians(TURN_AMPLITUDE_DEG) * scale
    return GaitParams(TURN_PERIOD, amp, math.radians(25.0), sign * TURN_LEFT, stand_body()), n


# --- behaviours -------------------------------------------------------------------------------


def run_distance(start: np.ndarray, *, persistent: bool = False, distance: float = 20.0,
                 speed: float = 50, amplitude: float = 50) -> Motion:
    """Walk straight ``distance`` cm (negative: backwards); persistent: walk until released."""
    check_finite(distance=distance, speed=speed, amplitude=amplitude)
    if persistent:
        p, _ = plan_walk(1000.0 if distance >= 0 else -1000.0, speed, amplitude)
        return gait_motion(start, replace(p, amplitude=math.radians(walk_params(speed, amplitude)[1])), 0, True)
    if abs(distance) < 0.5:
        return gait_motion(start, plan_walk(1.0, speed, amplitude)[0], 0)
    p, n = plan_walk(distance, speed, amplitude)
    return gait_motion(start, p, n)


def rotate(start: np.ndarray, *, persistent: bool = False, angle: float = 360.0) -> Motion:
    """Turn in place by ``angle`` degrees (positive: left / counter-clockwise)."""
    check_finite(angle=angle)
    if persistent:
        p, _ = plan_rotate(1000.0 if angle >= 0 else -1000.0)
        return gait_motion(start, replace(p, amplitude=math.radians(TURN_AMPLITUDE_DEG)), 0, True)
    if abs(angle) < 1.0:
        return gait_motion(start, plan_rotate(1.0)[0], 0)
    p, n = plan_rotate(angle)
    return gait_motion(start, p, n)


def move_strides(start: np.ndarray, *, persistent: bool = False, direction: str = "forward",
                 times: int = 1) -> Motion:
    """Take ``times`` full walking strides (gait cycles) forward or backward."""
    sign = check_choice(direction, {"forward": 1.0, "backward": -1.0}, "direction")
    times = check_count(times)
    period, amp = walk_params()
    cal = load_calibration()
    trim = cal.forward_trim if sign > 0 else cal.backward_trim
    p = GaitParams(period, math.radians(amp), math.radians(25.0), sign * FORWARD + trim * TURN_LEFT,
                   stand_body())
    return gait_motion(start, p, times, persistent)


CREEP_KNEE_DEG = 45.0


def creep(start: np.ndarray, *, persistent: bool = False, direction: str = "forward", speed: float = 50,
          duration: float = 0.0) -> Motion:
    """Creep low (bent knees, small steps) in ``direction``: one step cycle, or about ``duration`` s when > 0."""
    pattern = check_choice(direction, {"forward": FORWARD, "backward": -FORWARD, "left": -RIGHT, "right": RIGHT},
                      "direction")
    check_finite(speed=speed, duration=duration)
    s = min(max(float(speed), 0.0), 100.0) / 100.0
    period = 1.2 - 0.5 * s
    base = stand_body()
    base[KNEE_COLS] = math.radians(CREEP_KNEE_DEG)
    p = GaitParams(period, math.radians(15.0), math.radians(15.0), pattern, base)
    cycles = max(1, round(max(0.0, float(duration)) / period))
    return gait_motion(start, p, cycles, persistent)
