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

import importlib
import importlib.util
import math
import sys
import traceback
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

# the data a robot is made of lives in the leaf module robots.datatypes (the modules Robot builds on
# import it, not this one); re-exported here, where most callers look for it
from robots.datatypes import (
    MAX_WIRE_SERVOS,
    Base,
    Behaviour,
    Channel,
    Peripherals,
    RobotDataError,
    SceneObjectSpec,
    SceneSpec,
    Servo,
    ServoModelParams,
    ServoTable,
)

if TYPE_CHECKING:
    from robots.interface import Interface
    from robots.model import RobotModel
    from robots.tasks import Task

__all__ = [
    "Base",
    "Behaviour",
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
