"""``--mount-mcp`` arguments: ``NAME=COMMAND ARGS...`` (stdio) or ``NAME=URL`` (streamable HTTP).

:func:`parse_mount_arg` returns a :class:`MountSpec` or raises :class:`MountSpecError` (a
``ValueError`` and an ``argparse.ArgumentTypeError``: as ``type=`` it is a usage error with this
message, exit 2) naming the problem and the valid forms. ``str(spec)`` is canonical and parses back to the same spec.

* ``NAME``: the module (and channel) name the server's tools appear under, ``NAME.TOOL``; an
  ASCII letter or ``_``, then letters, digits, ``_`` or ``-`` (at most 40); not a shell built-in
  (``wait``, ``async``, ``SAVE``, ``RUN``) nor ``main``.
* ``COMMAND``: split like a POSIX shell (``shlex``): ``weather="python server.py --units metric"``.
  It runs with the SDK's safe environment (``HOME``, ``PATH``, ...) plus ``PYTHONPATH``,
  ``VIRTUAL_ENV``, ``LANG``/``LC_*``, ``TMPDIR``, ``MUJOCO_GL`` and ``GHOSTSHELL_*`` (no API keys);
  pass more with ``env VAR=value COMMAND``. A command starting with ``python`` or ``python3`` runs
  under ghostshell's own interpreter, so a server written with the same venv's ``mcp`` just works;
  one starting with ``ghostshell`` runs this installation's ``ghostshell`` (``python -m host``), so
  ``arm="ghostshell mcp --robot arm --lockstep"`` mounts another robot's shell.
* ``URL``: ``http://`` or ``https://`` with a host, e.g. ``http://127.0.0.1:8000/mcp``.
"""

from __future__ import annotations

import argparse
import re
import shlex
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING
from urllib.parse import urlsplit

from host.shell.types import BUILTINS, MAIN_CHANNEL

if TYPE_CHECKING:
    from host.shell.registry import Registry

FORMS = "NAME=COMMAND [ARGS...] (stdio) or NAME=http(s)://HOST[:PORT]/PATH (streamable HTTP)"
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_-]{0,39}")


class MountSpecError(argparse.ArgumentTypeError, ValueError):
    """A ``--mount-mcp`` argument that names no server; the message says why and the valid forms.

    An ``ArgumentTypeError``, so ``add_argument("--mount-mcp", type=parse_mount_arg, action="append")``
    prints this message (argparse replaces a plain ``ValueError``'s with "invalid ... value")."""


@dataclass(frozen=True)
class MountSpec:
    """One MCP server to mount: under ``name``, started as ``command`` or reached at ``url``."""

    name: str
    command: tuple[str, ...] = ()
    url: str | None = None

    def __post_init__(self) -> None:
        check_name(self.name)
        if bool(self.command) == (self.url is not None):
            raise MountSpecError(f"--mount-mcp {self.name}: give exactly one of a command or a URL ({FORMS})")
        if self.url is not None:
            _check_url(self.name, self.url)

    @property
    def kind(self) -> str:
        """``"stdio"`` or ``"http"``."""
        return "http" if self.url is not None else "stdio"

    def __str__(self) -> str:
        return f"{self.name}={self.url if self.url is not None else shlex.join(self.command)}"


def check_name(name: str) -> None:
    """Raise :class:`MountSpecError` unless ``name`` can name a mounted module."""
    if not _NAME.fullmatch(name):
        raise MountSpecError(f"--mount-mcp {name!r}: NAME must be an ASCII letter or _ followed by at most 39 "
                             f"letters, digits, _ or - (it prefixes the tools: NAME.TOOL); forms: {FORMS}")
    if name in BUILTINS or name == MAIN_CHANNEL:
        raise MountSpecError(f"--mount-mcp {name}: {name!r} is reserved by the shell; choose another NAME")


def _check_url(name: str, url: str) -> None:
    parts = urlsplit(url)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise MountSpecError(f"--mount-mcp {name}={url}: not an http(s) URL with a host; forms: {FORMS}")


def parse_mount_arg(text: str) -> MountSpec:
    """``NAME=COMMAND...`` or ``NAME=URL`` -> :class:`MountSpec` (raises :class:`MountSpecError`)."""
    name, eq, rest = text.partition("=")
    name, rest = name.strip(), rest.strip()
    if not eq or not rest:
        raise MountSpecError(f"--mount-mcp {text!r}: expected {FORMS}")
    check_name(name)
    if re.match(r"[A-Za-z][A-Za-z0-9+.-]*://", rest):
        if " " in rest:
            raise MountSpecError(f"--mount-mcp {name}: a URL takes no arguments ({rest!r}); forms: {FORMS}")
        return MountSpec(name, url=rest)
    try:
        argv = shlex.split(rest)
    except ValueError as exc:
        raise MountSpecError(f"--mount-mcp {name}: cannot split the command {rest!r}: {exc}") from None
    if not argv:
        raise MountSpecError(f"--mount-mcp {name}: empty command; forms: {FORMS}")
    return MountSpec(name, command=tuple(argv))


class McpMountError(RuntimeError):
    """A server that cannot be mounted; the message is one line naming it and the reason.

    Here, not in :mod:`host.mounts.mcp_mount` (which re-exports it with :func:`check_specs`): a command
    refuses a ``--mount-mcp`` NAME before anything starts without importing the MCP SDK (~1 s of CPU)."""


def check_specs(specs: Sequence[MountSpec], registry: Registry | None = None) -> None:
    """Raise :class:`McpMountError` when two specs share a NAME or a NAME is already a module."""
    seen: set[str] = set()
    modules = sorted(m.name for m in registry.modules()) if registry is not None else []
    taken = set(modules) | (set(registry.channels()) if registry is not None else set())
    for spec in specs:
        if spec.name in seen:
            raise McpMountError(f"--mount-mcp {spec.name}: NAME given twice; each server needs its own NAME")
        if spec.name in taken:
            raise McpMountError(f"--mount-mcp {spec.name}: {spec.name!r} is already a module or channel of this "
                                f"shell (modules: {', '.join(modules)}); choose another NAME")
        seen.add(spec.name)


def server_argv(spec: MountSpec) -> list[str]:
    """The argv a stdio ``spec`` starts: its command, with ``python``/``python3`` as ghostshell's own
    interpreter and ``ghostshell`` as this installation's (``python -m host``); see the module docstring."""
    argv = list(spec.command)
    if argv and argv[0] in ("python", "python3"):
        argv[0] = sys.executable
    elif argv and argv[0] == "ghostshell":
        argv[:1] = [sys.executable, "-m", "host"]
    return argv


def launch_problem(spec: MountSpec, *, timeout_s: float = 2.0) -> str | None:
    """Why the server of ``spec`` can be neither started nor reached, found without starting it (one line
    naming the spec), or None. A command checks its ``--mount-mcp`` with it before it starts a board or
    touches its ``--out`` folder; a server that starts and then fails is found when it is mounted.

    * stdio: the program (:func:`server_argv`'s first word) is found as the server's start would find it:
      on ``PATH``, or, with a ``/`` in it, a file that exists and may be executed;
    * http(s): the URL's host resolves and its port (default 80/443) accepts a TCP connection within
      ``timeout_s`` seconds (closed at once, nothing sent); a connection that times out is not refused here."""
    import os
    import shutil
    import socket

    if spec.url is None:
        program = server_argv(spec)[0]
        if shutil.which(program) is not None:
            return None
        if "/" in program:
            why = ("no such file" if not os.path.exists(program) else "a folder" if os.path.isdir(program)
                   else "not an executable file")
            return f"--mount-mcp {spec}: cannot start the server: {program}: {why}"
        return f"--mount-mcp {spec}: cannot start the server: no program {program!r} on PATH"
    parts = urlsplit(spec.url)
    host = parts.hostname or ""
    try:
        port = parts.port or (443 if parts.scheme == "https" else 80)
    except ValueError as exc:  # a port out of range or not a number
        return f"--mount-mcp {spec}: {exc}"
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            return None
    except socket.gaierror as exc:
        return f"--mount-mcp {spec}: cannot reach the server: host {host!r} not found ({exc.strerror or exc})"
    except ConnectionRefusedError:
        return f"--mount-mcp {spec}: cannot reach the server: nothing listens on {host}:{port} (connection refused)"
    except OSError:  # a timeout, no route: the mount reports it with its own timeout
        return None
