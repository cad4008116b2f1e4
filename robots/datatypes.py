"""The data a robot is made of, and the robot as the generic machinery reads it (a leaf module).

The frozen dataclasses of a robot package (servo table, channels, peripherals, scenes, base), its
error :class:`RobotDataError` and :class:`RobotData`, the protocol :mod:`robots.model`,
:mod:`robots.scenes`, :mod:`robots.motion`, :mod:`robots.generic` and :mod:`robots.interface` take a
robot as. :class:`robots.description.Robot` is built from these and has that protocol; it imports those
modules (for ``Robot.model()``, ``.behaviours``, ``.interface``, ``.tasks``), so they must not import it:
they import this module. :mod:`robots.description` re-exports every name here but :class:`RobotData`.

Units as in :mod:`robots.description`: joint angles in radians, speeds rad/s, torques N*m, lengths metres.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, Protocol

from protocol.messages import MAX_WIRE_SERVOS as _MAX_WIRE_SERVOS

__all__ = [
    "Base",
    "Behaviour",
    "Channel",
    "MAX_WIRE_SERVOS",
    "Peripherals",
    "RobotData",
    "RobotDataError",
    "SceneObjectSpec",
    "SceneSpec",
    "Servo",
    "ServoModelParams",
    "ServoTable",
]

#: The most servos a robot may have (:data:`protocol.messages.MAX_WIRE_SERVOS`): the wire's servo mask is
#: at most one u32 (one register on an MCU; :mod:`protocol.codec` uses a u16 mask up to 16 servos and a
#: u32 mask above).
MAX_WIRE_SERVOS = _MAX_WIRE_SERVOS


class RobotDataError(ValueError):
    """A robot package is malformed or inconsistent; the message says what and where (file:line)."""


@dataclass(frozen=True)
class Servo:
    """One servo: joint angles in radians, speed in rad/s.

    ``direction``: how the horn is mounted (horn angle = direction * (joint - neutral) + horn centre),
    for raw-servo tools. ``tags``: any further keys of its table entry (e.g. ``leg = 1``).
    """

    id: int
    name: str
    joint: str
    actuator: str
    neutral: float
    min: float
    max: float
    direction: int
    max_speed: float
    tags: Mapping[str, Any] = field(default_factory=dict, compare=False)

    @property
    def index(self) -> int:
        """Wire index (mask bit) of this servo: ``id - 1``."""
        return self.id - 1

    @property
    def leg(self) -> int | None:
        """The ``leg`` tag of a legged robot's servo (None when the entry has none)."""
        v = self.tags.get("leg")
        return int(v) if v is not None else None


@dataclass(frozen=True)
class ServoModelParams:
    """The servo model the board applies before writing MuJoCo ctrl (radians, N*m).

    ``resolution``: position quantisation (2 pi / steps per turn); ``deadband``: no drive while the
    error is below it; ``stall_torque``: the servo's stall torque when the table states it (the
    MJCF actuator's ``forcerange`` is what MuJoCo applies); ``model``: the servo's product class,
    informational (e.g. ``"STS3215"``).
    """

    resolution: float
    deadband: float
    stall_torque: float | None = None
    model: str = ""


@dataclass(frozen=True)
class ServoTable:
    """All servos in id order plus the shared servo-model parameters."""

    servos: tuple[Servo, ...]
    model: ServoModelParams

    def __len__(self) -> int:
        return len(self.servos)

    def __iter__(self) -> Iterator[Servo]:
        return iter(self.servos)

    def __getitem__(self, index: int) -> Servo:
        return self.servos[index]

    def by_name(self, name: str) -> Servo:
        """The servo called ``name`` (KeyError with the known names otherwise)."""
        for s in self.servos:
            if s.name == name:
                return s
        raise KeyError(f"no servo {name!r}; servos are {', '.join(s.name for s in self.servos)}")

    def by_joint(self, joint: str) -> Servo:
        """The servo driving MJCF joint ``joint`` (KeyError with the known joints otherwise)."""
        for s in self.servos:
            if s.joint == joint:
                return s
        raise KeyError(f"no servo drives joint {joint!r}; joints are {', '.join(s.joint for s in self.servos)}")

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

    @property
    def all_mask(self) -> int:
        """The wire mask covering every servo: bits 0..N-1."""
        return (1 << len(self.servos)) - 1

    def canonical_text(self) -> str:
        """The text :attr:`hash` is computed from: one line per servo, then the model line.

        Angles in radians and speeds in rad/s printed with ``%.9g`` (so a table that converts
        to the same doubles hashes the same), names as given, in id order.
        """
        lines = [f"servos {len(self.servos)}"]
        for s in self.servos:
            lines.append(f"{s.id} {s.name} {s.joint} {s.actuator} {s.neutral:.9g} {s.min:.9g} {s.max:.9g} "
                         f"{s.direction} {s.max_speed:.9g}")
        m = self.model
        lines.append(f"model {m.resolution:.9g} {m.deadband:.9g}")
        return "\n".join(lines) + "\n"

    @cached_property
    def hash(self) -> int:
        """u32: the first four bytes (big-endian) of SHA-256 over :meth:`canonical_text`.

        The board reports it in CAPS and the host refuses a board whose table differs from its own.
        """
        return int.from_bytes(hashlib.sha256(self.canonical_text().encode()).digest()[:4], "big")


@dataclass(frozen=True)
class Channel:
    """A motion channel: the servos its calls drive (0-based indices) and one line for the prompt."""

    name: str
    servos: tuple[int, ...]
    doc: str = ""


@dataclass(frozen=True)
class Peripherals:
    """What besides servos the robot has; an absent one leaves its functions out of the prompt.

    ``camera``: the MJCF camera the board renders (None: no camera); ``camera_label``: how
    captions and the video call it; ``screen``: a face screen; ``speaker``: speech and music;
    ``voices``: the speech engine's voice names; ``clips``: the music clips on the robot (None:
    any name plays).
    """

    camera: str | None = None
    camera_label: str = "camera"
    screen: bool = False
    speaker: bool = False
    voices: tuple[str, ...] = ("robot",)
    clips: tuple[str, ...] | None = None


@dataclass(frozen=True)
class SceneObjectSpec:
    """One object a scene adds to the world (MuJoCo primitives, metres, kg).

    ``shape``: box (``size`` = half sizes x y z), cylinder (radius, half height), sphere (radius);
    ``free``: a free joint (movable) or welded to the world (a table); ``topples``: counted in
    SIM_STATE's ``toppled`` when its axis leans more than :data:`robots.scenes.TOPPLE_DEG`.
    """

    name: str
    shape: str
    size: tuple[float, ...]
    pos: tuple[float, float, float]
    rgba: tuple[float, float, float, float] = (0.6, 0.6, 0.6, 1.0)
    mass: float | None = None
    free: bool = True
    friction: tuple[float, float, float] = (1.0, 0.005, 0.0001)
    topples: bool = False
    euler_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class SceneSpec:
    """A named world: the robot's MJCF plus objects."""

    name: str
    doc: str = ""
    objects: tuple[SceneObjectSpec, ...] = ()

    def object(self, name: str) -> SceneObjectSpec:
        """The object called ``name`` (KeyError with the scene's objects otherwise)."""
        for o in self.objects:
            if o.name == name:
                return o
        raise KeyError(f"scene {self.name!r} has no object {name!r}; objects: {', '.join(o.name for o in self.objects)}")


@dataclass(frozen=True)
class Base:
    """How the robot stands in the world.

    ``floating``: the MJCF root has a free joint (a mobile robot: IMU and SIM_STATE come from it)
    or the robot is fixed to the world (an arm). ``feet``: sites placed on the floor at start
    (the lowest one touches it); ``foot_radius``: the foot geom's radius (m) added to the site's
    height; ``spawn_height``: where the root starts before that placement (m).
    """

    floating: bool = False
    feet: tuple[str, ...] = ()
    foot_radius: float = 0.0
    spawn_height: float = 0.2


#: a behaviour generator: ``gen(start, *, persistent=False, **params) -> Motion`` (robots.motion.Motion)
Behaviour = Callable[..., Any]


class RobotData(Protocol):
    """A robot as the generic machinery reads it (:class:`robots.description.Robot` has all of it).

    Fields as documented on :class:`robots.description.Robot`; ``behaviours``: behaviour name ->
    generator (the generic ones included).
    """

    @property
    def name(self) -> str: ...
    @property
    def root(self) -> Path: ...
    @property
    def mjcf(self) -> Path: ...
    @property
    def servos(self) -> ServoTable: ...
    @property
    def poses(self) -> Mapping[str, tuple[float, ...]]: ...
    @property
    def channels(self) -> Mapping[str, Channel]: ...
    @property
    def peripherals(self) -> Peripherals: ...
    @property
    def base(self) -> Base: ...
    @property
    def start_pose(self) -> str: ...
    @property
    def interface_module(self) -> str | None: ...
    @property
    def default_vocabulary(self) -> str: ...
    @property
    def servo_count(self) -> int: ...
    @property
    def behaviours(self) -> Mapping[str, Behaviour]: ...
    def pose(self, name: str) -> tuple[float, ...]: ...
    def scene(self, name: str | None = None) -> SceneSpec: ...
