"""``--out DIR``, the artefact folder of every command that writes one, checked before anything starts.

:func:`out_dir` is the argparse ``type=`` every command's ``--out`` folder uses (``run``, ``demo``,
``chat``, ``replay``, ``tour``, ``mcp``, ``eval``, ``fuzz``): a path that is an existing file (a regular
file, ``/dev/null``, a socket), lies under a file, or names a place this process cannot create or write
a folder in (``/proc/x``, a read-only file system, a folder without write permission) is argparse's
usage error, exit status 2, one line naming the path and why, before any board starts or any file
is opened. Nothing is created: the folder itself is made when the command writes its first artefact.

Whether a folder can be written is found by trying, not by :func:`os.access`: root passes every
permission check, yet cannot make folders in ``/proc`` or ``/sys`` or on a read-only mount. The
probe makes a uniquely named empty folder (:func:`tempfile.mkdtemp`) in the path, or in its nearest
existing ancestor when the path does not exist yet, and removes it at once.

:func:`out_file` is the same for an output file (``render --out FILE``, ``pose``/``estop`` ``--log FILE``):
a folder, a device, a file under a missing folder or in one this process cannot write in is refused.

:func:`tcp_port_taken` answers why a localhost TCP port cannot be listened on (``mcp --http PORT``),
by binding it as the server would, before the board starts.
"""

from __future__ import annotations

import argparse
import errno
import os
import socket
import stat
import tempfile
from collections.abc import Collection
from pathlib import Path

__all__ = ["EarlierRun", "add_no_plots_argument", "clear_run_artefacts", "out_dir", "out_dir_problem", "out_file",
           "out_file_problem", "remove_unused_out", "session_start_files", "tcp_port_taken"]

_PROBE_PREFIX = ".ghostshell-write-probe-"
_EARLIER_PREFIX = ".ghostshell-earlier-"


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISREG(mode):
        return "a regular file"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a folder"


def _probe(folder: Path) -> str | None:
    """Why no folder can be made in the existing folder ``folder`` (its ``strerror``), or None."""
    try:
        os.rmdir(tempfile.mkdtemp(prefix=_PROBE_PREFIX, dir=folder))
    except OSError as e:
        return e.strerror or str(e)
    return None


def out_dir_problem(path: str | Path) -> str | None:
    """Why ``path`` cannot be (or become) a folder of artefacts, in a few words, or None when it can.

    It can when it is a folder this process can write in, or when it does not exist and its nearest
    existing ancestor is a folder this process can make folders in."""
    p = Path(path)
    if str(path) == "":
        return "is empty; give a folder"
    try:
        mode = os.stat(p).st_mode
    except FileNotFoundError:
        if p.is_symlink():  # makedirs would fail with "File exists" (a traceback in tour and eval)
            return f"is a symbolic link to {os.readlink(p)}, which does not exist; give a folder (existing or new)"
        mode = None
    except NotADirectoryError:
        mode = None  # a parent is a file: found below
    except OSError as e:
        return f"cannot be looked at ({e.strerror or e})"
    if mode is not None:
        if not stat.S_ISDIR(mode):
            return f"is {_kind(mode)}, not a folder; give a folder (existing or new)"
        why = _probe(p)
        return None if why is None else f"is a folder this process cannot write in ({why})"
    ancestor = p.absolute().parent
    while True:
        try:
            amode = os.stat(ancestor).st_mode
        except (FileNotFoundError, NotADirectoryError):
            if ancestor.parent == ancestor:
                return "cannot be created (no existing folder above it)"
            ancestor = ancestor.parent
            continue
        except OSError as e:
            return f"cannot be created: {ancestor} cannot be looked at ({e.strerror or e})"
        break
    if not stat.S_ISDIR(amode):
        return f"cannot be created: {ancestor} is {_kind(amode)}, not a folder"
    why = _probe(ancestor)
    return None if why is None else f"cannot be created: {ancestor} takes no new folder ({why})"


def out_dir(text: str) -> Path:
    """argparse ``type=`` for ``--out DIR``: the path, or :class:`argparse.ArgumentTypeError` saying why
    it cannot hold the artefacts (see :func:`out_dir_problem`)."""
    why = out_dir_problem(text)
    if why is not None:
        raise argparse.ArgumentTypeError(f"{text} {why}")
    return Path(text)


def out_file_problem(path: str | Path) -> str | None:
    """Why no file can be written at ``path`` (created, or an existing one replaced), in a few words, or None.

    It can when ``path`` is a regular file or does not exist, and its folder exists and this process can
    make entries in it (tried, as :func:`out_dir_problem` does). A folder, a device (``/dev/null``), a FIFO
    or a socket is refused: the commands write a file beside it and rename it over (``render``), which
    would replace a device node. The folder is not created."""
    p = Path(path)
    if str(path) == "":
        return "is empty; give a file"
    try:
        mode: int | None = os.stat(p).st_mode
    except (FileNotFoundError, NotADirectoryError):
        mode = None
    except OSError as e:
        return f"cannot be looked at ({e.strerror or e})"
    if mode is not None and not stat.S_ISREG(mode):
        return f"is {_kind(mode)}, not a file; give a file (existing or new)"
    folder = p.absolute().parent
    try:
        fmode = os.stat(folder).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return f"cannot be created: there is no folder {folder}"
    except OSError as e:
        return f"cannot be created: {folder} cannot be looked at ({e.strerror or e})"
    if not stat.S_ISDIR(fmode):
        return f"cannot be created: {folder} is {_kind(fmode)}, not a folder"
    why = _probe(folder)
    return None if why is None else f"cannot be created: {folder} takes no new file ({why})"


def out_file(text: str) -> Path:
    """argparse ``type=`` for an output file (``render --out FILE``, ``pose``/``estop`` ``--log FILE``): the
    path, or :class:`argparse.ArgumentTypeError` saying why it cannot be written (:func:`out_file_problem`)."""
    why = out_file_problem(text)
    if why is not None:
        raise argparse.ArgumentTypeError(f"{text} {why}")
    return Path(text)


def _run_artefact_paths(out: Path) -> list[Path]:
    """The files an earlier run left in the folder ``out`` (see :func:`clear_run_artefacts`)."""
    from host.run.artefacts import RUN_ARTEFACT_PATTERNS, RUN_ARTEFACTS

    if not out.is_dir():
        return []
    found = [out / name for name in RUN_ARTEFACTS]
    found += [p for pattern in RUN_ARTEFACT_PATTERNS for p in out.glob(pattern)]
    return [path for path in found if path.is_file() or path.is_symlink()]


def clear_run_artefacts(out: Path) -> list[str]:
    """Remove from the folder ``out`` the files an earlier run left there (:data:`host.run.artefacts.RUN_ARTEFACTS`,
    its photos); returns their names, sorted (empty when ``out`` does not exist or holds none). Every other
    file and folder (``speech/``, the user's own) is left alone. Errors: :class:`OSError` of a file that
    cannot be removed."""
    removed = []
    for path in _run_artefact_paths(out):
        path.unlink(missing_ok=True)
        removed.append(path.name)
    return sorted(removed)


def session_start_files() -> frozenset[str]:
    """The files in ``--out`` a session's start writes: the board's stderr and frame log, the host's, run.mcap."""
    from host.run.artefacts import FRAME_LOG_SUFFIXES

    return frozenset({"board.stderr", "run.mcap",
                      *(f"{end}_frames{s}" for end in ("host", "board") for s in FRAME_LOG_SUFFIXES)})


class EarlierRun:
    """The artefacts an earlier run left in ``out`` (:func:`clear_run_artefacts`'s files), set aside while a new
    run starts: renamed into a hidden folder of ``out`` (``.ghostshell-earlier-*``) when made.

    :meth:`discard` once the new run has started (the files are then gone, as :func:`clear_run_artefacts` leaves
    them); :meth:`restore` when the run was refused before it began (a board that cannot start, a servo bus or
    CAN adapter that cannot be opened): what the refused start wrote is removed and the earlier files come back
    byte for byte. ``only``: set aside only these names (``chat`` keeps an earlier run's other files; it sets
    aside those its session's start overwrites, :func:`session_start_files`). ``names``: the files set aside,
    sorted. Errors: :class:`OSError` when a file cannot be moved (the ones already moved are put back first).
    A process killed in between leaves them in the hidden folder."""

    def __init__(self, out: Path, *, only: Collection[str] | None = None) -> None:
        self.out = out
        self.names: list[str] = []
        self._folder: Path | None = None
        self._only = only
        found = self._paths()
        if not found:
            return
        self._folder = Path(tempfile.mkdtemp(prefix=_EARLIER_PREFIX, dir=out))
        try:
            for path in found:
                os.replace(path, self._folder / path.name)
                self.names.append(path.name)
        except OSError:
            self._put_back()  # nothing of a new run there yet: only what was moved goes back
            raise
        self.names.sort()

    def _paths(self) -> list[Path]:
        return [p for p in _run_artefact_paths(self.out) if self._only is None or p.name in self._only]

    def discard(self) -> None:
        """Delete the files set aside (the new run has started). Never raises."""
        import shutil

        folder, self._folder = self._folder, None
        if folder is not None:
            shutil.rmtree(folder, ignore_errors=True)

    def restore(self) -> None:
        """Put the files set aside back in ``out``, over what a refused start wrote (no-op after :meth:`discard`)."""
        if self._folder is None:
            return
        for path in self._paths():  # what the refused start began
            path.unlink(missing_ok=True)
        self._put_back()

    def _put_back(self) -> None:
        folder, self._folder = self._folder, None
        if folder is not None:
            for path in folder.iterdir():
                os.replace(path, self.out / path.name)
            folder.rmdir()


def remove_unused_out(out: Path) -> None:
    """Remove the folder ``out`` a run created and then refused to run in (a link refused when opened):
    the files it began (an empty frame log) and the folder, when nothing else is in it. Never raises."""
    try:
        clear_run_artefacts(out)
        out.rmdir()
    except OSError:
        pass


def tcp_port_taken(port: int, host: str = "127.0.0.1") -> str | None:
    """Why a server cannot listen on ``host:port`` (one phrase, e.g. ``"port 8000 is in use ..."``), or None.

    Binds the port as the server would (``SO_REUSEADDR`` set, as uvicorn does on POSIX, so a port
    left in TIME_WAIT is free) and closes it again."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        if os.name == "posix":
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as e:
            if e.errno == errno.EADDRINUSE:
                return f"port {port} is in use on {host} (another server listens there); pick another PORT"
            if e.errno == errno.EACCES:
                return f"port {port} on {host} needs privileges this process lacks; pick a port above 1023"
            return f"cannot listen on {host}:{port} ({e.strerror or e})"
    return None


def add_no_plots_argument(parser: argparse.ArgumentParser, what: str = "run", *, skips_matplotlib: bool = True) -> None:
    """``--no-plots`` (``args.no_plots``) of every command whose runs draw timeline.png and joints.png
    (``run``, ``demo``, ``chat``, ``eval``, ``mcp``); ``what`` names what one run is in the help;
    ``skips_matplotlib``: the command then never imports matplotlib (``eval`` still draws eval.png)."""
    also = " and matplotlib's import" if skips_matplotlib else ""
    parser.add_argument("--no-plots", action="store_true",
                        help=f"draw no timeline.png / joints.png (the other artefacts are written; saves "
                             f"~0.25 s of CPU per {what}{also})")
