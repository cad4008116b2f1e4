"""A record of robots whose MJCF passed the loader's check, so loading one again skips MuJoCo.

:func:`robots.loader.check_against_mjcf` compiles a robot's MJCF and checks its servo table, camera
and foot sites against it. Importing MuJoCo for that costs ~0.2 s, more than the rest of a command
that only loads the robot (a usage error, ``robots show``, ``log decode``): the check ran on every
command. Now a pass is recorded and the next load with the same inputs skips it.

An entry's name is a SHA-256 over what the check is given and what does it: the checking code's
source files (:data:`CHECKER_SOURCES`, so a new check rechecks every robot), :data:`CHECK_VERSION`,
MuJoCo's version (from its package metadata, without importing it), the MJCF's absolute path, the
servo table, the camera and the foot sites. It holds a SHA-256 over the names, sizes and *contents*
of every file under the MJCF's folder (meshes and textures included; only ``__pycache__`` and
``.git`` are left out). A hit needs that digest unchanged, so any edit, however quick after the last
load, checks again: contents, not modification times, which a coarse file-system clock can hide.

Only a **self-contained** robot is recorded, one whose every input the digest covers; any other is
checked every time:

- nothing under the folder is a symbolic link, and the MJCF is not one (MuJoCo resolves relative
  paths from the link's folder, the digest would read the target's);
- no XML file under the folder (any file starting with ``<``) names a file or folder by an absolute
  path, ``~`` or through ``..`` (``file=`` and a cube texture's ``fileup=`` etc., ``meshdir=``,
  ``texturedir=``, ``assetdir=``: includes, attached models, meshes and textures all stay inside);
- the folder holds at most :data:`MAX_FILES` entries and :data:`MAX_BYTES` bytes, all regular
  files or folders (hashing more could cost more than the check);
- the digest taken before the check equals the one taken after it (an edit saved while MuJoCo read
  the files is not recorded as a pass).

Failures are never recorded: a broken robot is checked, and refused, every time. At most
:data:`MAX_ENTRIES` entries are kept (the oldest are removed when one is written).

Folder: ``$GHOSTSHELL_MJCF_CHECK_CACHE`` when it is an absolute path (``~`` expanded), else (unset or
empty) platformdirs' user cache folder ``ghostshell/mjcf-checks`` (``~/.cache/ghostshell/mjcf-checks``
on Linux); ``off``, or any value that is not an absolute path, checks every time. Entries are named
``mjcf-check-<sha256>.json``; nothing else in the folder is read or removed. Entries are
written to a temporary file and renamed into place, so parallel processes never read half an entry;
a cache that cannot be read or written is ignored and the check runs.

Written here rather than taken from a library: none caches a validation result keyed on file
contents. The scheme is make's (a target and what it was made from), with content digests as in
ccache.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import stat
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

__all__ = ["CACHE_ENV", "CHECKER_SOURCES", "CHECK_VERSION", "MAX_BYTES", "MAX_ENTRIES", "MAX_FILES", "Snapshot",
           "cache_folder", "passed", "record", "snapshot"]

#: bump to check every recorded robot again (a change of CHECKER_SOURCES does that by itself)
CHECK_VERSION = 2
#: the checking code (robots/): its bytes are part of every entry's name
CHECKER_SOURCES = ("loader.py", "mjcf_index.py", "mjcf_check_cache.py")
CACHE_ENV = "GHOSTSHELL_MJCF_CHECK_CACHE"
#: a folder with more entries (files and folders) or bytes than this is checked every time
MAX_FILES = 2_000
MAX_BYTES = 64 << 20
#: entries kept; writing one more removes the oldest
MAX_ENTRIES = 256
#: an entry file is a few hundred bytes; a bigger one is damaged and ignored
MAX_ENTRY_BYTES = 4_096
#: the names this module writes, and the only ones it ever removes (the folder may be a user's own)
_ENTRY = re.compile(r"^mjcf-check-[0-9a-f]{64}\.json$")
_TEMP = re.compile(r"^\.mjcf-check-.*\.tmp$")
_SKIP_DIRS = frozenset({"__pycache__", ".git"})
#: an XML attribute naming a file or folder: the file itself, an include, an attached model, a mesh/texture folder
_PATH_ATTR = re.compile(r"^(?:file[a-z]*|meshdir|texturedir|assetdir)$")

#: the folder's digest, or None when the robot is not self-contained
Snapshot = str | None


def cache_folder() -> Path | None:
    """Where entries live: ``$GHOSTSHELL_MJCF_CHECK_CACHE`` when it is an absolute path (``~`` expanded),
    else platformdirs' user cache folder when it is unset or empty; None (check every time) for ``off``
    and for any other value (a relative path would put a folder wherever the command runs)."""
    env = os.path.expanduser((os.environ.get(CACHE_ENV) or "").strip())
    if env:
        return Path(env) if os.path.isabs(env) else None
    import platformdirs

    return Path(platformdirs.user_cache_dir("ghostshell", appauthor=False)) / "mjcf-checks"


def _mujoco_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("mujoco")
    except PackageNotFoundError:
        return "?"


def _entry(folder: Path, mjcf: Path, inputs: Sequence[object]) -> Path:
    return folder / f"mjcf-check-{_key(mjcf, inputs)}.json"


def _key(mjcf: Path, inputs: Sequence[object]) -> str:
    h = hashlib.sha256()
    here = Path(__file__).resolve().parent
    for name in CHECKER_SOURCES:
        h.update((here / name).read_bytes())
    for part in (CHECK_VERSION, _mujoco_version(), str(mjcf.absolute()), *inputs):
        h.update(repr(part).encode("utf-8", "surrogatepass"))
        h.update(b"\0")
    return h.hexdigest()


def _read_regular(path: Path, size: int) -> bytes | None:
    """``path``'s bytes if it is still a regular file of ``size`` bytes (never blocks on a FIFO)."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0))
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or st.st_size != size:
            return None
        data = os.read(fd, size + 1)
        while len(data) <= size:
            more = os.read(fd, size + 1 - len(data))
            if not more:
                break
            data += more
        return data if len(data) == size else None
    finally:
        os.close(fd)


def _outside(value: str) -> bool:
    """True when an attribute value names a place outside the folder (absolute, ``~``, or through ``..``)."""
    text = value.strip().replace("\\", "/")
    return text.startswith(("/", "~")) or re.match(r"^[A-Za-z]:", text) is not None or ".." in text.split("/")


def _paths_inside(xml: bytes) -> bool:
    """True when the XML document parses and none of its path attributes (``file``, ``file*`` of a cube
    texture, ``meshdir``, ``texturedir``, ``assetdir``; values decoded, character references included)
    names a place outside the folder."""
    from xml.etree import ElementTree

    try:
        root = ElementTree.fromstring(xml)
    except (ElementTree.ParseError, ValueError):  # not one well-formed document: MuJoCo's reading is unknown
        return False
    return not any(_PATH_ATTR.match(name) and _outside(value) for el in root.iter() for name, value in el.attrib.items())


def snapshot(mjcf: Path) -> Snapshot:
    """SHA-256 over the names, sizes and contents of every file under ``mjcf``'s folder, or None when
    the robot is not self-contained (see the module docstring) or something cannot be read."""
    try:
        if mjcf.is_symlink():
            return None
        folder = mjcf.absolute().parent
        h = hashlib.sha256()
        entries = total = 0
        for root, dirs, files in os.walk(folder):
            dirs[:] = sorted(d for d in dirs if d not in _SKIP_DIRS)
            for name in [*dirs, *sorted(files)]:
                entries += 1
                p = Path(root) / name
                st = os.lstat(p)
                if entries > MAX_FILES or stat.S_ISLNK(st.st_mode):
                    return None
                if stat.S_ISDIR(st.st_mode):
                    continue
                if not stat.S_ISREG(st.st_mode) or (total := total + st.st_size) > MAX_BYTES:
                    return None
                data = _read_regular(p, st.st_size)
                if data is None:
                    return None
                xml = data.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"<")  # any XML, whatever its suffix
                if xml and not _paths_inside(data):
                    return None
                h.update(f"{p.relative_to(folder)}\0{len(data)}\0".encode("utf-8", "surrogateescape"))
                h.update(data)
        return h.hexdigest()
    except OSError:
        return None


def passed(mjcf: Path, inputs: Sequence[object]) -> bool:
    """True when this MJCF with these check ``inputs`` (servo table, camera, feet) passed before and
    no file under its folder changed since."""
    folder = cache_folder()
    if folder is None:
        return False
    try:
        path = _entry(folder, mjcf, inputs)
        st = os.lstat(path)
        if not stat.S_ISREG(st.st_mode) or st.st_size > MAX_ENTRY_BYTES:  # a link, FIFO or device: never opened
            return False
        raw = _read_regular(path, st.st_size)
        if raw is None:
            return False
        want = json.loads(raw)["digest"]
    except (OSError, ValueError, KeyError, TypeError):
        return False
    return isinstance(want, str) and snapshot(mjcf) == want


def record(mjcf: Path, inputs: Sequence[object], before: Snapshot) -> None:
    """Record that the check passed; ``before``: :func:`snapshot` taken before the check ran (recorded
    only when the folder is self-contained and unchanged since)."""
    folder = cache_folder()
    if folder is None or before is None or snapshot(mjcf) != before:
        return
    tmp: str | None = None
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".mjcf-check-", suffix=".tmp")
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump({"mjcf": str(mjcf.absolute()), "digest": before}, f)
        os.replace(tmp, _entry(folder, mjcf, inputs))
        tmp = None
        _prune(folder)
    except OSError:
        pass
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


def _prune(folder: Path) -> None:
    """Keep the newest :data:`MAX_ENTRIES` entries; remove this module's temporary files over an hour old
    (a writer killed between create and rename). Files of any other name are never touched."""
    now = time.time()
    entries: list[tuple[float, Path]] = []
    for p in folder.iterdir():
        with contextlib.suppress(OSError):
            mtime = os.lstat(p).st_mtime
            if _TEMP.match(p.name) and now - mtime > 3600:
                p.unlink()
            elif _ENTRY.match(p.name):
                entries.append((mtime, p))
    entries.sort(reverse=True)
    for _, p in entries[MAX_ENTRIES:]:
        with contextlib.suppress(OSError):
            p.unlink()
