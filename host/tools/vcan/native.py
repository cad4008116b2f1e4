"""SocketCAN ``vcan`` interfaces on this machine's own kernel, where it has the ``vcan`` module.

:func:`native_plan` decides whether ``ghostshell vcan`` can run a command here directly: every
interface already up (nothing to do), or, as root with ``ip`` (iproute2), the missing ones can be
created (``ip link add dev NAME type vcan`` loads the module on demand; a kernel without it refuses
that, and the command then runs in User-Mode Linux instead, :mod:`host.tools.vcan.uml`).
:func:`run_native` creates them, loads further modules (``modprobe``, best effort), runs the
command with this terminal's stdin/stdout/stderr and deletes the interfaces it created.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["NativePlan", "interface_up", "native_plan", "run_native"]

#: The SocketCAN link type in /sys/class/net/NAME/type (ARPHRD_CAN).
ARPHRD_CAN = "280"
_SYSTEM_PATH = "/usr/sbin:/usr/bin:/sbin:/bin"


def interface_up(name: str) -> bool:
    """True when this kernel has a SocketCAN interface ``name`` that is not down."""
    path = Path("/sys/class/net") / name
    try:
        return (path / "type").read_text().strip() == ARPHRD_CAN and (path / "operstate").read_text().strip() != "down"
    except OSError:
        return False


@dataclass
class NativePlan:
    """What running natively needs: the interfaces to create (empty: all are up already)."""

    create: list[str] = field(default_factory=list)


def _ip(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([shutil.which("ip", path=_SYSTEM_PATH) or "ip", *args], capture_output=True, text=True,
                          check=False)


def native_plan(ifaces: Sequence[str]) -> NativePlan | None:
    """A plan to run with ``ifaces`` on this kernel, or None when it cannot (then use UML).

    Probes by creating the first missing interface (and deleting it again): only the kernel knows
    whether it can load ``vcan``.
    """
    missing = [name for name in ifaces if not interface_up(name)]
    if not missing:
        return NativePlan([])
    if not sys.platform.startswith("linux") or os.geteuid() != 0 or shutil.which("ip", path=_SYSTEM_PATH) is None:
        return None
    probe = missing[0]
    if Path("/sys/class/net", probe).exists():  # exists but is down, or is not CAN: not ours to change
        return None
    if _ip("link", "add", "dev", probe, "type", "vcan").returncode != 0:
        return None
    _ip("link", "delete", "dev", probe)
    return NativePlan(missing)


def run_native(argv: Sequence[str], plan: NativePlan, *, fd: bool = True, txqueuelen: int | None = None,
               modules: Sequence[str] = (), cwd: Path | None = None, env: Mapping[str, str] | None = None) -> int:
    """Create ``plan.create`` (MTU 72 with ``fd``, else 16), load ``modules``, run ``argv``, delete
    what was created; returns the command's exit status (127 not found, 126 not executable,
    128+N killed by signal N). A KeyboardInterrupt stops the command (SIGINT, then SIGKILL after
    5 s), cleans up and propagates."""
    created: list[str] = []
    try:
        for name in plan.create:
            res = _ip("link", "add", "dev", name, "type", "vcan")
            if res.returncode != 0:
                raise OSError(f"cannot create {name}: {res.stderr.strip()}")
            created.append(name)
            for args in (("mtu", "72" if fd else "16"),
                         *((("txqueuelen", str(txqueuelen)),) if txqueuelen is not None else ()), ("up",)):
                res = _ip("link", "set", name, *args)
                if res.returncode != 0:
                    raise OSError(f"cannot set {name} {' '.join(args)}: {res.stderr.strip()}")
        modprobe = shutil.which("modprobe", path=_SYSTEM_PATH)
        for module in modules:
            if Path("/sys/module", module.replace("-", "_")).exists():
                continue
            if modprobe is None or subprocess.run([modprobe, module], capture_output=True, check=False).returncode:
                print(f"ghostshell vcan: kernel module {module} could not be loaded; what needs it will fail",
                      file=sys.stderr)
        try:
            proc = subprocess.Popen(list(argv), cwd=cwd, env=dict(env) if env is not None else None)
        except FileNotFoundError:
            print(f"ghostshell vcan: {argv[0]}: command not found", file=sys.stderr)
            return 127
        except PermissionError as e:
            print(f"ghostshell vcan: {argv[0]}: {e.strerror}", file=sys.stderr)
            return 126
        try:
            status = proc.wait()
        except KeyboardInterrupt:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(5)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
            raise
        return status if status >= 0 else 128 - status
    finally:
        for name in created:
            _ip("link", "delete", "dev", name)
