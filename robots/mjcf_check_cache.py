"""A record of robots whose MJCF passed the loader's check, so loading one again skips MuJoCo.

:func:`robots.loader.check_against_mjcf` compiles a robot's MJCF and checks its servo table, camera
and foot sites against it. Importing MuJoCo for that costs ~0.2 s, more than the rest of a command
that only loads the robot (a usage error, ``robots show``, ``log decode``): the check ran on every
command. Now a pass is recorded and the next load with the same inputs skips it.

An entry's name is a SHA-256 over what the check is given and what does it: the checking code's
source files (:data:`CHECKER_SOURCES`, so a new check rechecks every robot), :data:`CHECK_VERSION`,
MuJoCo's version (from its package metadata, without importing it), the MJCF's resolved path, the
servo table, the camera and the foot sites. It holds a SHA-256 over the *contents* of every file the check may
depend on: every file under the MJCF's folder (meshes and textures included; ``__pycache__`` and
hidden folders left out) and the included XML files outside it that the check read. A hit needs
that digest unchanged, so any edit, however quick after the last load, checks again (contents,
not modification times: a coarse file-system clock cannot hide an edit). Only passes are recorded;
a failing robot is checked, and refused, every time. A folder of more than :data:`MAX_FILES` files
or :data:`MAX_BYTES` bytes is not recorded (hashing it could cost more than the check).

Folder: ``$GHOSTSHELL_MJCF_CHECK_CACHE``, else platformdirs' user cache folder ``ghostshell/mjcf-checks``;
``GHOSTSHELL_MJCF_CHECK_CACHE=off`` checks every time. Entries are written to a temporary file and
renamed into place (parallel processes never read half an entry); a cache that cannot be read or
written is ignored and the check runs.

The scheme is make's (a target and what it was built from), with content digests as in ccache.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path

__all__ = ["CACHE_ENV", "CHECK_VERSION", "MAX_BYTES", "MAX_FILES", "cache_folder", "passed", "record"]

#: bump to check every recorded robot again (a change of CHECKER_SOURCES does that by itself)
CHECK_VERSION = 1
#: the checking code (robots/): its bytes are part of every entry's name
CHECKER_SOURCES = ("loader.py", "mjcf_index.py", "mjcf_check_cache.py")
CACHE_ENV = "GHOSTSHELL_MJCF_CHECK_CACHE"
#: a folder bigger than this (files, bytes) is checked every time
MAX_FILES = 2_000
MAX_BYTES = 64 << 20


def cache_folder() -> Path | None:
    """Where entries live; None when ``$GHOSTSHELL_MJCF_CHECK_CACHE`` is ``off``."""
    env = os.environ.get(CACHE_ENV)
    if env and env.strip().lower() in ("off", "0", "no", "false"):
        return None
    if env and env.strip():
        return Path(env)
    import platformdirs

    return Path(platformdirs.user_cache_dir("ghostshell", appauthor=False)) / "mjcf-checks"


def _mujoco_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("mujoco")
    except PackageNotFoundError:
        return "?"


def _key(mjcf: Path, inputs: Sequence[object]) -> str:
    h = hashlib.sha256()
    here = Path(__file__).resolve().parent
    for name in CHECKER_SOURCES:
        h.update((here / name).read_bytes())
    for part in (CHECK_VERSION, _mujoco_version(), str(mjcf.resolve()), *inputs):
        h.update(repr(part).encode("utf-8", "surrogatepass"))
        h.update(b"\0")
    return h.hexdigest()


def _folder_files(folder: Path) -> list[Path] | None:
    """Every regular file under ``folder`` (sorted), or None past :data:`MAX_FILES` / :data:`MAX_BYTES`."""
    out: list[Path] = []
    total = 0
    for root, dirs, files in os.walk(folder):
        dirs[:] = sorted(d for d in dirs if d != "__pycache__" and not d.startswith("."))
        for name in files:
            p = Path(root) / name
            try:
                if not p.is_file():
                    continue
                total += p.stat().st_size
            except OSError:
                continue
            out.append(p)
            if len(out) > MAX_FILES or total > MAX_BYTES:
                return None
    return sorted(out)


def _digest(mjcf: Path, outside: Iterable[str]) -> str | None:
    """SHA-256 over the relative names and contents of the MJCF folder's files and ``outside``."""
    folder = mjcf.resolve().parent
    files = _folder_files(folder)
    if files is None:
        return None
    h = hashlib.sha256()
    try:
        for p in files:
            h.update(str(p.relative_to(folder)).encode("utf-8", "surrogateescape") + b"\0")
            h.update(p.read_bytes())
        total = 0
        for name in outside:  # the entry's list: only regular files, within the same byte bound
            p = Path(name)
            if not p.is_file() or (total := total + p.stat().st_size) > MAX_BYTES:
                return None
            h.update(name.encode("utf-8", "surrogateescape") + b"\0")
            h.update(p.read_bytes())
    except OSError:
        return None
    return h.hexdigest()


def passed(mjcf: Path, inputs: Sequence[object]) -> bool:
    """True when this MJCF with these check ``inputs`` (servo table, camera, feet) passed before and
    none of the files it depends on changed since."""
    folder = cache_folder()
    if folder is None:
        return False
    try:
        entry = json.loads((folder / f"{_key(mjcf, inputs)}.json").read_text(encoding="utf-8"))  # OSError: no entry
        outside = [str(x) for x in entry["outside"]]
        want = str(entry["digest"])
    except (OSError, ValueError, KeyError, TypeError):
        return False
    return _digest(mjcf, outside) == want


def record(mjcf: Path, inputs: Sequence[object], read: Iterable[Path]) -> None:
    """Record that the check passed; ``read``: the XML files it read (the MJCF and its includes)."""
    folder = cache_folder()
    if folder is None:
        return
    inside = mjcf.resolve().parent
    outside = sorted({str(p.resolve()) for p in read if not p.resolve().is_relative_to(inside)})
    digest = _digest(mjcf, outside)
    if digest is None:
        return
    tmp: str | None = None
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".entry-", suffix=".tmp")
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump({"mjcf": str(mjcf.resolve()), "outside": outside, "digest": digest}, f)
        os.replace(tmp, folder / f"{_key(mjcf, inputs)}.json")  # OSError (sources unreadable too): not recorded
        tmp = None
    except OSError:
        pass
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
