"""A robot's real servo bus as data: which wire protocol, baud and servo models, and its calibration.

Two optional files in a robot package (next to ``robot.toml``):

``hardware.toml`` — what the bus is (written by hand, or by ``ghostshell robots new``)::

    protocol = "sts"        # "sts" (Feetech SCS/STS) or "dxl2" (ROBOTIS Dynamixel Protocol 2.0)
    baud = 1000000          # the servos' baud rate
    model = 777             # model number every servo reports (STS3215: 777; XL330-M288: 1200)
    [models]                # optional per-servo exceptions, by servo name
    gripper = 1200

``calibration.toml`` — written by ``ghostshell robots calibrate``; per servo, by name::

    [servo.shoulder_pan]
    id = 1
    offset_steps = 37       # raw reading at the servo table's neutral, minus the register centre
    direction = -1          # +1: the horn turns as the servo table says; -1: mounted the other way
    min_steps = 812         # the mechanical range seen while calibrating (raw register values)
    max_steps = 3300

Conversion (4096-step servos, both protocols: register centre :data:`STEP_CENTRE` = 2048, one step =
the servo table's resolution): ``raw = STEP_CENTRE + offset_steps + direction * table_direction *
round((q - neutral) / step)`` and back. Without a calibration ``offset_steps = 0, direction = +1``
and the range is the whole register (0..4095). The servo-table horn convention is
:mod:`robots.datatypes` ``Servo.direction``; the plant (``firmware_sim.plant``) and the C firmware's
generated servo table use the same formula with the calibration absent.

Pure data and arithmetic: no I/O beyond reading and writing these two files; errors are
:class:`robots.datatypes.RobotDataError` naming file, servo and value.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from robots.datatypes import RobotDataError, Servo

__all__ = [
    "BUS_PROTOCOLS",
    "CALIBRATION_FILE",
    "HARDWARE_FILE",
    "STEP_CENTRE",
    "STEP_MAX",
    "BusProtocol",
    "Calibration",
    "Hardware",
    "ServoCalibration",
    "load_calibration",
    "load_hardware",
    "save_calibration",
    "step_limits",
    "steps_to_rad",
    "rad_to_steps",
]

BusProtocol = Literal["sts", "dxl2"]
BUS_PROTOCOLS: tuple[BusProtocol, ...] = ("sts", "dxl2")
HARDWARE_FILE = "hardware.toml"
CALIBRATION_FILE = "calibration.toml"
#: position register value of the horn centre (4096-step servos: half a turn), both protocols
STEP_CENTRE = 2048
STEP_MAX = 4095
#: model numbers the servos report (register 3 on STS, address 0 on Dynamixel X)
DEFAULT_MODEL: dict[str, int] = {"sts": 777, "dxl2": 1200}
DEFAULT_BAUD: dict[str, int] = {"sts": 1_000_000, "dxl2": 1_000_000}


@dataclass(frozen=True)
class Hardware:
    """The bus a robot's servos hang on (``hardware.toml``; defaults when the file is absent)."""

    protocol: BusProtocol = "sts"
    baud: int = 1_000_000
    model: int = 777
    models: Mapping[str, int] = field(default_factory=dict)

    def model_of(self, servo: Servo) -> int:
        """The model number ``servo`` must report."""
        return int(self.models.get(servo.name, self.model))


@dataclass(frozen=True)
class ServoCalibration:
    """One servo's calibration (raw register steps; ``direction`` is +1 or -1)."""

    id: int
    offset_steps: int = 0
    direction: int = 1
    min_steps: int = 0
    max_steps: int = STEP_MAX


@dataclass(frozen=True)
class Calibration:
    """Per servo name; a servo without an entry is uncalibrated (offset 0, direction +1, full range)."""

    servos: Mapping[str, ServoCalibration] = field(default_factory=dict)

    def of(self, servo: Servo) -> ServoCalibration:
        return self.servos.get(servo.name) or ServoCalibration(servo.id)


def _read(path: Path) -> dict[str, Any]:
    try:
        return tomllib.loads(path.read_text())
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise RobotDataError(f"{path}: {e}") from None


def _int(path: Path, where: str, v: object, lo: int, hi: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise RobotDataError(f"{path}: {where} must be an integer in {lo}..{hi}, got {v!r}")
    return v


def load_hardware(folder: Path, servos: list[Servo] | None = None) -> Hardware:
    """``folder/hardware.toml`` (defaults when absent). ``servos`` checks the per-servo names."""
    path = Path(folder) / HARDWARE_FILE
    if not path.is_file():
        return Hardware()
    d = _read(path)
    unknown = set(d) - {"protocol", "baud", "model", "models"}
    if unknown:
        raise RobotDataError(f"{path}: unknown key {sorted(unknown)[0]!r} (protocol, baud, model, models)")
    protocol = d.get("protocol", "sts")
    if protocol not in BUS_PROTOCOLS:
        raise RobotDataError(f"{path}: protocol must be one of {', '.join(BUS_PROTOCOLS)}, got {protocol!r}")
    baud = _int(path, "baud", d.get("baud", DEFAULT_BAUD[protocol]), 9600, 4_500_000)
    model = _int(path, "model", d.get("model", DEFAULT_MODEL[protocol]), 0, 0xFFFF)
    models = d.get("models", {})
    if not isinstance(models, dict):
        raise RobotDataError(f"{path}: [models] must be a table of servo name = model number")
    names = {s.name for s in servos} if servos is not None else None
    for name, m in models.items():
        if names is not None and name not in names:
            raise RobotDataError(f"{path}: [models] names no servo {name!r} (servos: {', '.join(sorted(names))})")
        _int(path, f"models.{name}", m, 0, 0xFFFF)
    return Hardware(protocol, baud, model, dict(models))


def load_calibration(folder: Path, servos: list[Servo]) -> Calibration:
    """``folder/calibration.toml`` checked against ``servos`` (empty when absent)."""
    path = Path(folder) / CALIBRATION_FILE
    if not path.is_file():
        return Calibration()
    d = _read(path)
    by_name = {s.name: s for s in servos}
    out: dict[str, ServoCalibration] = {}
    for name, e in dict(d.get("servo", {})).items():
        s = by_name.get(name)
        if s is None:
            raise RobotDataError(f"{path}: [servo.{name}] names no servo of this robot")
        if not isinstance(e, dict):
            raise RobotDataError(f"{path}: [servo.{name}] must be a table")
        sid = _int(path, f"servo.{name}.id", e.get("id", s.id), 0, 253)
        if sid != s.id:
            raise RobotDataError(f"{path}: servo {name} is id {s.id} in the servo table, {sid} here")
        direction = e.get("direction", 1)
        if direction not in (1, -1):
            raise RobotDataError(f"{path}: servo.{name}.direction must be 1 or -1, got {direction!r}")
        cal = ServoCalibration(
            sid, _int(path, f"servo.{name}.offset_steps", e.get("offset_steps", 0), -STEP_MAX, STEP_MAX), direction,
            _int(path, f"servo.{name}.min_steps", e.get("min_steps", 0), 0, STEP_MAX),
            _int(path, f"servo.{name}.max_steps", e.get("max_steps", STEP_MAX), 0, STEP_MAX))
        if cal.min_steps >= cal.max_steps:
            raise RobotDataError(f"{path}: servo {s.id} ({name}): min_steps {cal.min_steps} is not below "
                                 f"max_steps {cal.max_steps} (an inverted range)")
        out[name] = cal
    return Calibration(out)


def save_calibration(folder: Path, calibration: Calibration, servos: list[Servo]) -> Path:
    """Write ``folder/calibration.toml`` (servo-table order); returns its path."""
    lines = ["# written by `ghostshell robots calibrate`; raw register steps (robots/hardware.py)", ""]
    for s in servos:
        c = calibration.servos.get(s.name)
        if c is None:
            continue
        lines += [f"[servo.{s.name}]", f"id = {c.id}", f"offset_steps = {c.offset_steps}",
                  f"direction = {c.direction}", f"min_steps = {c.min_steps}", f"max_steps = {c.max_steps}", ""]
    path = Path(folder) / CALIBRATION_FILE
    path.write_text("\n".join(lines))
    return path


def rad_to_steps(servo: Servo, cal: ServoCalibration, q: float, step: float) -> int:
    """Raw position register value for joint angle ``q`` (rad), not clamped."""
    return STEP_CENTRE + cal.offset_steps + cal.direction * servo.direction * int(round((q - servo.neutral) / step))


def steps_to_rad(servo: Servo, cal: ServoCalibration, raw: int, step: float) -> float:
    """Joint angle (rad) of raw position register value ``raw``."""
    return servo.neutral + cal.direction * servo.direction * (raw - STEP_CENTRE - cal.offset_steps) * step


def step_limits(servo: Servo, cal: ServoCalibration, step: float) -> tuple[int, int]:
    """The raw register range a goal may take: the servo table's joint range ``[min, max]`` converted
    (rounded inwards) and intersected with the calibrated mechanical range and 0..4095.

    Raises :class:`RobotDataError` (servo id and name) when the intersection is empty: a calibration
    whose range does not overlap the joint's (an inverted or shifted calibration)."""
    a = math.ceil((servo.min - servo.neutral) / step - 1e-9)
    b = math.floor((servo.max - servo.neutral) / step + 1e-9)
    if cal.direction * servo.direction < 0:
        a, b = -b, -a
    lo = max(0, cal.min_steps, STEP_CENTRE + cal.offset_steps + a)
    hi = min(STEP_MAX, cal.max_steps, STEP_CENTRE + cal.offset_steps + b)
    if lo > hi:
        raise RobotDataError(
            f"servo {servo.id} ({servo.name}): its joint range {math.degrees(servo.min):.0f}..{math.degrees(servo.max):.0f} deg "
            f"is steps {STEP_CENTRE + cal.offset_steps + a}..{STEP_CENTRE + cal.offset_steps + b}, outside the calibrated "
            f"{cal.min_steps}..{cal.max_steps}: recalibrate (ghostshell robots calibrate)")
    return lo, hi
