"""Where robots are found: built-in packages under ``robots/`` and user robot folders.

Search order for ``--robot NAME`` (the first folder holding ``NAME/robot.toml`` wins, like ``PATH``):

1. ``--robots-dir DIR`` (every command that takes ``--robot`` accepts it);
2. ``$GHOSTSHELL_ROBOTS`` (one folder, or several separated by ``os.pathsep``);
3. the user robot folder, ``platformdirs.user_data_dir("ghostshell")/robots`` (where
   ``ghostshell robots new`` writes);
4. the built-in robots, the folders of this package.

``NAME`` may also be a path to a robot folder (it contains a ``/`` or is an existing folder).
:data:`DEFAULT_ROBOT` is what every command uses without ``--robot``: the built-in robot whose
robot.toml says ``default = true`` (no code names a particular robot).
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path

from robots.description import Robot, RobotDataError
from robots.loader import ROBOT_FILE, load_robot_dir

__all__ = ["BUILTIN_DIR", "DEFAULT_ROBOT", "RobotEntry", "RobotNotFound", "find_robot", "list_robots", "load_robot",
           "new_robots_dir", "robots_dir_arg", "robots_dir_problem", "search_path", "user_robots_dir"]

BUILTIN_DIR = Path(__file__).resolve().parent
ENV_VAR = "GHOSTSHELL_ROBOTS"


def _default_robot() -> str:
    """The built-in robot marked ``default = true`` in its robot.toml (exactly one must be)."""
    marked = []
    for toml in sorted(BUILTIN_DIR.glob(f"*/{ROBOT_FILE}")):
        with open(toml, "rb") as f:
            if tomllib.load(f).get("default") is True:
                marked.append(toml.parent.name)
    if len(marked) != 1:
        raise RobotDataError(f"{BUILTIN_DIR}: exactly one built-in robot must say default = true, found {marked}")
    return marked[0]


#: the robot every command drives without ``--robot``
DEFAULT_ROBOT = _default_robot()


class RobotNotFound(RobotDataError):
    """``--robot`` names no robot on the search path (the message lists the known ones)."""


def user_robots_dir() -> Path:
    """The user robot folder (platformdirs' user data dir for ``ghostshell``, then ``robots``)."""
    import platformdirs

    return Path(platformdirs.user_data_dir("ghostshell")) / "robots"


def robots_dir_problem(robots_dir: str | Path) -> str | None:
    """Why ``robots_dir`` (a ``--robots-dir`` to search) cannot be searched, or None: it must be an existing
    folder (a mistyped one would otherwise be passed over and the next folder's robot used)."""
    p = Path(robots_dir).expanduser()
    if not p.exists():
        return f"{robots_dir}: no such folder (give a folder of robots, each NAME/robot.toml)"
    if not p.is_dir():
        return f"{robots_dir} is not a folder (give a folder of robots, each NAME/robot.toml)"
    return None


def robots_dir_arg(text: str) -> str:
    """argparse ``type=`` for ``--robots-dir``: the folder, or a usage error (:func:`robots_dir_problem`)."""
    import argparse

    why = robots_dir_problem(text)
    if why is not None:
        raise argparse.ArgumentTypeError(why)
    return text


def new_robots_dir(robots_dir: str | Path | None = None) -> Path:
    """Where ``ghostshell robots new`` writes: ``robots_dir`` if given, else the first folder of
    ``$GHOSTSHELL_ROBOTS``, else :func:`user_robots_dir` (the first user folder of :func:`search_path`)."""
    return next(folder for folder, builtin in search_path(robots_dir) if not builtin)


def search_path(robots_dir: str | Path | None = None) -> list[tuple[Path, bool]]:
    """Folders searched for robots, first wins: ``(folder, built-in?)``."""
    dirs: list[tuple[Path, bool]] = []
    if robots_dir:
        dirs.append((Path(robots_dir).expanduser(), False))
    for part in os.environ.get(ENV_VAR, "").split(os.pathsep):
        if part.strip():
            dirs.append((Path(part.strip()).expanduser(), False))
    dirs.append((user_robots_dir(), False))
    dirs.append((BUILTIN_DIR, True))
    return dirs


@dataclass(frozen=True)
class RobotEntry:
    """One robot folder found on the search path (not loaded)."""

    name: str
    folder: Path
    builtin: bool
    shadowed_by: Path | None = None


def list_robots(robots_dir: str | Path | None = None) -> list[RobotEntry]:
    """Every robot folder on the search path, in search order (shadowed ones marked)."""
    seen: dict[str, Path] = {}
    out: list[RobotEntry] = []
    for folder, builtin in search_path(robots_dir):
        if not folder.is_dir():
            continue
        for child in sorted(folder.iterdir()):
            if not child.name.startswith(".") and (child / ROBOT_FILE).is_file():  # (.NAME.new-PID: being written)
                name = child.name
                out.append(RobotEntry(name, child, builtin, seen.get(name)))
                seen.setdefault(name, child)
    return out


def find_robot(name: str, robots_dir: str | Path | None = None) -> tuple[Path, bool]:
    """The folder of robot ``name`` and whether it is built in; :class:`RobotNotFound` otherwise."""
    as_path = Path(name).expanduser()
    if "/" in name or os.sep in name or (as_path.is_dir() and (as_path / ROBOT_FILE).is_file()):
        if not (as_path / ROBOT_FILE).is_file():
            raise RobotNotFound(f"{as_path}: no {ROBOT_FILE} in that folder")
        folder = as_path.resolve()
        return folder, folder.parent == BUILTIN_DIR
    for folder, builtin in search_path(robots_dir):
        candidate = folder / name
        if (candidate / ROBOT_FILE).is_file():
            return candidate.resolve(), builtin
    known = sorted({e.name for e in list_robots(robots_dir)})
    raise RobotNotFound(f"no robot {name!r}; robots: {', '.join(known) or 'none'} "
                        f"(searched {', '.join(str(f) for f, _ in search_path(robots_dir))})")


@cache
def _load(folder: Path, builtin: bool) -> Robot:
    return load_robot_dir(folder, builtin=builtin)


def load_robot(name: str | None = None, robots_dir: str | Path | None = None) -> Robot:
    """The robot ``name`` (default :data:`DEFAULT_ROBOT`; loaded once per folder and process);
    :class:`RobotDataError` says what is wrong."""
    folder, builtin = find_robot(DEFAULT_ROBOT if name is None else name, robots_dir)
    return _load(folder, builtin)


def robot_names(robots_dir: str | Path | None = None) -> Sequence[str]:
    """The names ``--robot`` accepts (first on the search path wins)."""
    return sorted({e.name for e in list_robots(robots_dir)})
