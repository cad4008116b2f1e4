"""A robot as one value: the :class:`Robot` that host, board, eval, video and the commands all take.

A robot is a folder of data (``robots/<name>/`` for the built-in ones, or a user robot folder, see
:mod:`robots.registry`) read by :func:`robots.loader.load_robot_dir`:

==================  ==============================================================================
``robot.toml``      name, title, files, poses the run and the board use, base, channels,
                    peripherals, scenes (see :mod:`robots.loader` for every key)
MJCF                the MuJoCo model (position actuators, joint ranges)
servo table         ids 1..N, joints, actuators, limits, speeds, directions, servo-model figures
poses               named joint-angle vectors (degrees in the file, radians here)
tasks (optional)    instructions with function-token ground truths (the paper's format)
interface (opt.)    a Python module of function stubs (:mod:`robots.interface`) the LLM sees
behaviours (opt.)   a Python module ``BEHAVIOURS: name -> gen(start, *, persistent, **params) -> Motion``
==================  ==============================================================================

Units: every angle here is a *joint* angle in radians (the servo table's file says degrees),
speeds rad/s, torques N*m, lengths metres. Servo ``id`` N is wire index N-1 (mask bit N-1).

Every robot has the generic functions ``pose`` and ``joint_move`` (:mod:`robots.generic`) on top of
whatever its interface module declares, so any LLM can drive any robot on day one.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import math
import sys
import traceback
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

from protocol.messages import MAX_WIRE_SERVOS as _MAX_WIRE_SERVOS

if TYPE_CHECKING:
    from robots.interface import Interface
    from robots.model import RobotModel
    from robots.tasks import Task

__all__ = [
    "Base",
    "Channel",
    "MAX_WIRE_SERVOS",
    "Peripherals",
    "Robot",
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


@dataclass(frozen=True, eq=False)
class Robot:
    """One robot: everything host and board need, read from its folder (see the module docstring).

    Compared and hashed by identity (one loaded value per folder, :func:`robots.registry.load_robot`
    caches it). Python modules of the package (behaviours, interface) are imported on first use, so
    the board, which needs only data, never imports them.
    """

    name: str
    title: str
    description: str
    root: Path
    mjcf: Path
    servos: ServoTable
    poses: Mapping[str, tuple[float, ...]]
    channels: Mapping[str, Channel]
    peripherals: Peripherals
    scenes: Mapping[str, SceneSpec]
    default_scene: str
    base: Base
    start_pose: str
    rest_pose: str
    safe_pose: str
    tasks_path: Path | None = None
    behaviours_module: str | None = None
    interface_module: str | None = None
    default_vocabulary: str = "default"
    demo_task_id: int | None = None
    #: the poses ``ghostshell tour`` drives through, in order (robot.toml ``tour``; default every pose,
    #: then the first again)
    tour_poses: tuple[str, ...] = ()
    data: Mapping[str, Path] = field(default_factory=dict)
    #: the video's follow camera: distance_m, azimuth_deg, elevation_deg, lookat_z (m); absent keys: defaults
    view: Mapping[str, float] = field(default_factory=dict)
    builtin: bool = False
    sources: Mapping[str, Path] = field(default_factory=dict)

    @property
    def servo_count(self) -> int:
        """N: servos on the wire (ids 1..N)."""
        return len(self.servos)

    @property
    def servo_table_hash(self) -> int:
        """u32 hash of the servo table (:attr:`ServoTable.hash`), what CAPS reports."""
        return self.servos.hash

    def pose(self, name: str) -> tuple[float, ...]:
        """Named pose ``name`` (radians, servo order); KeyError names the robot's poses."""
        try:
            return self.poses[name]
        except KeyError:
            raise KeyError(f"{self.name} has no pose {name!r}; poses: {', '.join(self.poses)}") from None

    def scene(self, name: str | None = None) -> SceneSpec:
        """The scene ``name`` (default: the robot's default scene); KeyError names the valid ones."""
        key = self.default_scene if name is None else name
        try:
            return self.scenes[key]
        except KeyError:
            raise KeyError(f"{self.name} has no scene {key!r}; scenes: {', '.join(self.scenes)}") from None

    def model(self, scene: str | None = None) -> RobotModel:
        """Compile the MJCF with ``scene``'s objects (:class:`robots.model.RobotModel`)."""
        from robots.model import load_model

        return load_model(self, scene)

    # -- the Python parts (imported on first use) ----------------------------------------------------

    def module(self, name: str) -> ModuleType:
        """Import the package's Python module ``name`` (``robots.<name>.<module>`` for a built-in robot)."""
        return self._module(name)

    def _module(self, name: str) -> ModuleType:
        if self.builtin:
            return importlib.import_module(f"robots.{self.name}.{name}")
        path = self.root / f"{name}.py"
        mod_name = f"ghostshell_robot_{self.name}_{name}"
        if mod_name in sys.modules:
            return sys.modules[mod_name]
        spec = importlib.util.spec_from_file_location(mod_name, path)
        if spec is None or spec.loader is None:
            raise RobotDataError(f"{path}: cannot import this robot module")
        mod = importlib.util.module_from_spec(spec)
        sys.modules[mod_name] = mod
        try:
            spec.loader.exec_module(mod)
        except Exception as e:  # a user robot's module: one line with its file:line, not a traceback
            sys.modules.pop(mod_name, None)
            line = getattr(e, "lineno", None) if isinstance(e, SyntaxError) else next(
                (f.lineno for f in reversed(traceback.extract_tb(e.__traceback__)) if f.filename == str(path)), None)
            raise RobotDataError(f"{path}{f':{line}' if line else ''}: cannot import this robot module "
                                 f"({type(e).__name__}: {e})") from None
        return mod

    @cached_property
    def behaviours(self) -> Mapping[str, Behaviour]:
        """Behaviour name -> generator: the generic ones (``pose``, ``joint_move``) and the module's.

        The module's ``BEHAVIOURS`` is a dict, or a function ``BEHAVIOURS(robot) -> dict`` (so a user
        package's generators can take their limits and servo indices from this robot)."""
        from robots.generic import generic_behaviours

        out: dict[str, Behaviour] = dict(generic_behaviours(self))
        if self.behaviours_module:
            path = self.root / (self.behaviours_module + ".py")
            mod = self._module(self.behaviours_module)
            own = getattr(mod, "BEHAVIOURS", None)
            if callable(own) and not isinstance(own, Mapping):
                try:
                    own = own(self)
                except Exception as e:  # the package's code: one line with its place, not a traceback
                    line = next((f.lineno for f in reversed(traceback.extract_tb(e.__traceback__))
                                 if f.filename == str(path)), None)
                    raise RobotDataError(f"{path}{f':{line}' if line else ''}: BEHAVIOURS(robot) failed "
                                         f"({type(e).__name__}: {e})") from None
            if not isinstance(own, Mapping):
                raise RobotDataError(f"{path}: needs BEHAVIOURS, a dict name -> generator or a function "
                                     "robot -> that dict")
            out.update(own)
        return out

    @cached_property
    def interface(self) -> Interface:
        """The function stubs the LLM sees (:class:`robots.interface.Interface`), generic ones included."""
        from robots.interface import build_interface

        mod = self._module(self.interface_module) if self.interface_module else None
        try:
            return build_interface(self, mod)
        except (TypeError, AttributeError, KeyError) as e:  # VOCABULARIES of the wrong shape: one line
            where = self.root / f"{self.interface_module}.py" if self.interface_module else self.root / "robot.toml"
            raise RobotDataError(f"{where}: VOCABULARIES must map vocabulary -> {{module name: class of stubs}} "
                                 f"({type(e).__name__}: {e})") from None

    @cached_property
    def tasks(self) -> Mapping[int, Task]:
        """Task id -> :class:`robots.tasks.Task` (empty when the robot has none)."""
        from robots.tasks import load_tasks

        return load_tasks(self.tasks_path) if self.tasks_path is not None else {}

    @property
    def tour(self) -> tuple[str, ...]:
        """The poses ``ghostshell tour`` drives through."""
        return self.tour_poses or (*self.poses, next(iter(self.poses)))

    @property
    def demo_task(self) -> int | None:
        """The task ``ghostshell demo`` shows: robot.toml's ``demo_task``, else the first task with a ground truth."""
        if self.demo_task_id is not None:
            return self.demo_task_id
        runnable = sorted(i for i, t in self.tasks.items() if t.ground_truth is not None)
        return runnable[0] if runnable else None

    def channel_of_servo(self, index: int) -> str | None:
        """The motion channel that drives servo ``index`` (0-based), if one does."""
        for c in self.channels.values():
            if index in c.servos:
                return c.name
        return None

    def describe(self) -> str:
        """A few lines for ``ghostshell robots show``."""
        deg = math.degrees
        lines = [f"{self.name}: {self.title} ({self.servo_count} servos{'' if self.builtin else ', user robot'})",
                 f"  {self.description}" if self.description else "",
                 f"  folder: {self.root}", f"  mjcf:   {self.mjcf.name}",
                 f"  servo table hash: {self.servo_table_hash:#010x}",
                 "  servos: " + ", ".join(f"{s.id}:{s.name}[{deg(s.min):.0f}..{deg(s.max):.0f}]" for s in self.servos),
                 "  poses: " + ", ".join(self.poses),
                 "  channels: " + (", ".join(f"{c.name}({len(c.servos)})" for c in self.channels.values())
                                   or "none (pose and joint_move run on the generic channel joints)"),
                 "  peripherals: " + (", ".join(p for p, on in (("camera", self.peripherals.camera),
                                                                 ("screen", self.peripherals.screen),
                                                                 ("speaker", self.peripherals.speaker)) if on)
                                      or "none"),
                 "  scenes: " + ", ".join(self.scenes), f"  tasks: {len(self.tasks)}"]
        return "\n".join(x for x in lines if x)
