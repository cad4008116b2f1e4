"""CoCo, the 12-servo spider-like quadruped: MJCF, servo table and named poses as data.

``MJCF_PATH`` is the MuJoCo model; :func:`load_servo_table` reads ``servos.toml`` (the one
servo table host and board share); :func:`load_poses` reads ``poses.toml``. All angles
returned are joint angles in radians, servo-id order (id N is wire index N-1).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from functools import cache
from pathlib import Path

__all__ = [
    "LEG_NAMES",
    "MJCF_PATH",
    "POSES_PATH",
    "SERVO_COUNT",
    "SERVO_TABLE_PATH",
    "Servo",
    "ServoModelParams",
    "ServoTable",
    "load_poses",
    "load_servo_table",
]

_HERE = Path(__file__).resolve().parent
MJCF_PATH: Path = _HERE / "coco.xml"
SERVO_TABLE_PATH: Path = _HERE / "servos.toml"
POSES_PATH: Path = _HERE / "poses.toml"
SERVO_COUNT = 12
#: Leg number (1..4) -> short name used in joint names.
LEG_NAMES: dict[int, str] = {1: "fr", 2: "fl", 3: "bl", 4: "br"}


@dataclass(frozen=True)
class Servo:
    """One servo: angles in radians (joint side), speed in rad/s."""

    id: int
    name: str
    joint: str
    actuator: str
    neutral: float
    min: float
    max: float
    direction: int
    max_speed: float
    leg: int | None = None

    @property
    def index(self) -> int:
        """Wire index (mask bit) of this servo: ``id - 1``."""
        return self.id - 1


@dataclass(frozen=True)
class ServoModelParams:
    """Hobby-servo behaviour the board applies before writing MuJoCo ctrl (radians)."""

    resolution: float
    deadband: float


@dataclass(frozen=True)
class ServoTable:
    """All 12 servos in id order plus the shared servo-model parameters."""

    servos: tuple[Servo, ...]
    model: ServoModelParams

    def __len__(self) -> int:
        return len(self.servos)

    def __iter__(self):  # type: ignore[no-untyped-def]
        return iter(self.servos)

    def __getitem__(self, index: int) -> Servo:
        return self.servos[index]

    def by_name(self, name: str) -> Servo:
        """The servo called ``name`` (KeyError with the known names otherwise)."""
        for s in self.servos:
            if s.name == name:
                return s
        raise KeyError(f"no servo {name!r}; servos are {', '.join(s.name for s in self.servos)}")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.servos)

    @property
    def neutral(self) -> tuple[float, ...]:
        return tuple(s.neutral for s in self.servos)

    @property
    def mins(self) -> tuple[float, ...]:
        return tuple(s.min for s in self.servos)

    @property
    def maxs(self) -> tuple[float, ...]:
        return tuple(s.max for s in self.servos)

    @property
    def max_speeds(self) -> tuple[float, ...]:
        return tuple(s.max_speed for s in self.servos)


class RobotDataError(ValueError):
    """servos.toml or poses.toml is malformed (the message says where)."""


@cache
def load_servo_table(path: Path | None = None) -> ServoTable:
    """Read and validate the servo table (ids 1..12 in order, min < neutral-range < max)."""
    p = Path(path) if path is not None else SERVO_TABLE_PATH
    data = tomllib.loads(p.read_text())
    servos: list[Servo] = []
    for n, row in enumerate(data.get("servo", []), start=1):
        try:
            s = Servo(
                id=int(row["id"]),
                name=str(row["name"]),
                joint=str(row["joint"]),
                actuator=str(row["actuator"]),
                neutral=math.radians(float(row["neutral_deg"])),
                min=math.radians(float(row["min_deg"])),
                max=math.radians(float(row["max_deg"])),
                direction=int(row["direction"]),
                max_speed=math.radians(float(row["max_speed_dps"])),
                leg=int(row["leg"]) if "leg" in row else None,
            )
        except KeyError as e:
            raise RobotDataError(f"{p}: servo entry {n} lacks {e.args[0]!r}") from None
        if s.id != n:
            raise RobotDataError(f"{p}: servo entry {n} has id {s.id}; ids must run 1..{SERVO_COUNT} in order")
        if not s.min < s.max or not s.min <= s.neutral <= s.max:
            raise RobotDataError(f"{p}: servo {s.name}: need min < max and neutral inside [min, max]")
        if s.direction not in (-1, 1) or s.max_speed <= 0:
            raise RobotDataError(f"{p}: servo {s.name}: direction must be +-1 and max_speed > 0")
        servos.append(s)
    if len(servos) != SERVO_COUNT:
        raise RobotDataError(f"{p}: {len(servos)} servos, CoCo has {SERVO_COUNT}")
    model = data.get("model", {})
    params = ServoModelParams(
        resolution=math.radians(float(model.get("resolution_deg", 0.088))),
        deadband=math.radians(float(model.get("deadband_deg", 0.2))),
    )
    return ServoTable(tuple(servos), params)


@cache
def load_poses(path: Path | None = None) -> dict[str, tuple[float, ...]]:
    """Named poses: name -> 12 joint targets in radians, servo-id order (validated against limits)."""
    p = Path(path) if path is not None else POSES_PATH
    table = load_servo_table()
    data = tomllib.loads(p.read_text()).get("poses", {})
    poses: dict[str, tuple[float, ...]] = {}
    for name, degs in data.items():
        if not isinstance(degs, list) or len(degs) != SERVO_COUNT:
            raise RobotDataError(f"{p}: pose {name!r} needs {SERVO_COUNT} values in servo-id order")
        rad = tuple(math.radians(float(v)) for v in degs)
        for s, v in zip(table, rad):
            if not s.min - 1e-9 <= v <= s.max + 1e-9:
                raise RobotDataError(
                    f"{p}: pose {name!r}: {s.name} = {math.degrees(v):.1f} deg outside "
                    f"[{math.degrees(s.min):.0f}, {math.degrees(s.max):.0f}]"
                )
        poses[name] = rad
    for required in ("neutral", "stand", "sit", "crouch"):
        if required not in poses:
            raise RobotDataError(f"{p}: pose {required!r} is missing")
    return poses
