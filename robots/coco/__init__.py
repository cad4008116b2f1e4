"""CoCo, the 12-servo spider-like quadruped: its package (``robot.toml`` and the files it names).

Everything generic reads CoCo through :func:`robots.load_robot` ("coco"). This module keeps CoCo's
own code (motions, gaits, interface) and its tests short: ``ROBOT`` is CoCo's
:class:`~robots.description.Robot`; :func:`load_servo_table` and :func:`load_poses` return its
servo table and named poses (joint angles in radians, servo-id order: id N is wire index N-1).
"""

from __future__ import annotations

from pathlib import Path

from robots.description import RobotDataError, Servo, ServoModelParams, ServoTable
from robots.registry import load_robot

__all__ = [
    "LEG_NAMES",
    "MJCF_PATH",
    "POSES_PATH",
    "ROBOT",
    "RobotDataError",
    "SERVO_COUNT",
    "SERVO_TABLE_PATH",
    "Servo",
    "ServoModelParams",
    "ServoTable",
    "load_poses",
    "load_servo_table",
]

_HERE = Path(__file__).resolve().parent
#: CoCo as one value (robots/coco/robot.toml)
ROBOT = load_robot(str(_HERE))
MJCF_PATH: Path = ROBOT.mjcf
SERVO_TABLE_PATH: Path = ROBOT.sources["servo_table"]
POSES_PATH: Path = ROBOT.sources["poses"]
SERVO_COUNT = ROBOT.servo_count
#: Leg number (1..4) -> short name used in joint names.
LEG_NAMES: dict[int, str] = {1: "fr", 2: "fl", 3: "bl", 4: "br"}


def load_servo_table() -> ServoTable:
    """CoCo's servo table (robots/coco/servos.toml)."""
    return ROBOT.servos


def load_poses() -> dict[str, tuple[float, ...]]:
    """CoCo's named poses: name -> 12 joint targets in radians, servo-id order."""
    return dict(ROBOT.poses)
