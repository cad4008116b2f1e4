"""Run a command on a real Linux kernel with SocketCAN ``vcan`` interfaces, via User-Mode Linux.

A kernel without the ``vcan`` module (this machine's) runs SocketCAN code inside a throwaway
User-Mode Linux (UML) guest (``ghostshell vcan -- COMMAND``, :mod:`host.commands.vcan`; the tests
import this module through ``tests/support/uml.py``): Debian's ``user-mode-linux`` package ships ``/usr/bin/linux.uml``
and the ``can``, ``can-raw``, ``can-dev`` and ``vcan`` modules under
``/usr/lib/uml/modules/<kernel version>/``. The guest boots in about 2 s without KVM, its root
file system is the host's root through hostfs (``root=/dev/root rootfstype=hostfs rootflags=/``),
so the checkout's venv python and every path are the same inside and out, except ``/tmp`` (the
guest's own; ``keep`` folders shared, ``copy_back`` paths copied out at the end). PID 1 is
``host/tools/vcan/uml_init.py`` (see there for what it mounts and why).

Use::

    from host.tools.vcan.uml import run_in_uml, socketcan_skip_reason
    result = run_in_uml([sys.executable, "-c", "..."], run_dir=tmp_path, timeout=60)
    assert result.returncode == 0, result.describe()

Costs: a boot is ~2 s; the guest is pinned to one CPU (``taskset``), which makes UML roughly 3x
faster than letting it migrate; python start-up over hostfs is slower than native (a whole
pty-based task runs ~4x slower inside), so keep the number of boots small — run a whole
pytest session in one boot rather than one boot per test.

Output streams: the guest's hostfs writes through to the host file at once (``hostfs_write_end``
calls the host's ``write``), so ``on_output`` gets the job's stdout and stderr while it runs, read
back from ``stdout.txt``/``stderr.txt`` by a thread (:class:`_Tail`).
"""

from __future__ import annotations

import functools
import hashlib
import threading
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from host.tools.vcan.native import interface_up

UML_KERNEL = Path("/usr/bin/linux.uml")
UML_MODULES_ROOT = Path("/usr/lib/uml/modules")
INIT_SCRIPT = Path(__file__).resolve().with_name("uml_init.py")
XSTATE_SHIM_SOURCE = Path(__file__).resolve().with_name("uml_xstate_shim.c")
#: The folder holding the ``host`` package (the checkout): always reachable inside, and the default cwd.
REPO_ROOT = Path(__file__).resolve().parents[3]
#: Boot + power-off allowance added to the job's own timeout for the outer watchdog, seconds.
BOOT_MARGIN_S = 60.0
#: CAN FD MTU (``CANFD_MTU`` in linux/can.h); the classic one is 16.
CANFD_MTU = 72
CAN_MTU = 16


class UmlError(RuntimeError):
    """The guest did not report an exit status: boot failure, init failure or outer timeout."""


@dataclass(frozen=True)
class UmlResult:
    """What a UML run left behind.

    returncode: the job's exit status (124 = killed at its timeout, 128+N = killed by signal N).
    stdout/stderr: the job's output (text, decoded with ``errors="replace"``).
    console: the guest kernel's console (boot log), useful when something fails.
    run_dir: host folder holding ``stdout.txt``, ``stderr.txt``, ``console.txt``, ``exit_status``.
    seconds: wall time from starting UML to its exit (boot + job + power-off).
    """

    returncode: int
    stdout: str
    stderr: str
    console: str
    run_dir: Path
    seconds: float

    def describe(self, tail: int = 4000) -> str:
        """A failure message: exit status, then the tails of stdout and stderr."""
        return (
            f"UML job exited {self.returncode} after {self.seconds:.1f} s (run dir {self.run_dir})\n"
            f"--- stdout (tail) ---\n{self.stdout[-tail:]}\n--- stderr (tail) ---\n{self.stderr[-tail:]}"
        )


@functools.cache
def uml_modules_dir() -> Path | None:
    """The module tree of the installed ``linux.uml`` (``linux.uml --version`` names it; else the
    newest version holding ``vcan.ko``), or None."""
    if not UML_MODULES_ROOT.is_dir():
        return None
    try:
        version = subprocess.run([str(UML_KERNEL), "--version"], capture_output=True, text=True, timeout=10,
                                 check=False).stdout.strip()
    except (OSError, subprocess.TimeoutExpired):
        version = ""
    exact = UML_MODULES_ROOT / version if version else None
    if exact is not None and (exact / "kernel/drivers/net/can/vcan.ko").is_file():
        return exact
    versions = sorted(p for p in UML_MODULES_ROOT.iterdir() if (p / "kernel/drivers/net/can/vcan.ko").is_file())
    return versions[-1] if versions else None


def uml_unavailable_reason() -> str | None:
    """Why UML SocketCAN runs are impossible here (None when they are possible)."""
    if not sys.platform.startswith("linux"):
        return "User-Mode Linux needs a Linux host"
    if not os.access(UML_KERNEL, os.X_OK):
        return f"{UML_KERNEL} not found (apt-get install user-mode-linux; .ci/setup does it)"
    if uml_modules_dir() is None:
        return f"no vcan.ko under {UML_MODULES_ROOT}/<version>/ (the user-mode-linux package ships it)"
    if shutil.which("ip") is None:
        return "the `ip` tool (iproute2) is missing; it creates the vcan interfaces"
    if _cc() is None:
        return "no C compiler (cc/gcc) to build the xstate shim linux.uml needs on this CPU (apt-get install gcc)"
    return None


def _cc() -> str | None:
    return shutil.which("cc") or shutil.which("gcc")


def xstate_shim() -> Path:
    """Build (once per source version) the LD_PRELOAD shim that lets Debian's 6.1 UML run on CPUs
    whose XSAVE area is larger than UML's FP buffer (AMX); see ``uml_xstate_shim.c``.

    Returns the path of the shared object (cached in the system temp folder). Raises UmlError if
    the compiler fails.
    """
    source = XSTATE_SHIM_SOURCE.read_bytes()
    digest = hashlib.sha256(source).hexdigest()[:16]
    target = Path(tempfile.gettempdir()) / f"ghostshell-uml-xstate-{digest}-{os.getuid()}.so"
    if target.is_file():
        return target
    cc = _cc()
    if cc is None:
        raise UmlError("no C compiler to build the UML xstate shim")
    partial = target.with_suffix(f".{os.getpid()}.tmp")
    proc = subprocess.run(
        [cc, "-O2", "-Wall", "-shared", "-fPIC", "-o", str(partial), str(XSTATE_SHIM_SOURCE), "-ldl"],
        capture_output=True,
        text=True,
        check=False,
    )
    if proc.returncode != 0:
        raise UmlError(f"building the UML xstate shim failed:\n{proc.stderr}")
    os.replace(partial, target)
    return target


def native_vcan(name: str = "vcan0") -> bool:
    """True when this kernel already has an *up* SocketCAN interface ``name``."""
    return interface_up(name)


def socketcan_skip_reason(name: str = "vcan0") -> str | None:
    """None if SocketCAN tests can run (natively on ``name`` or inside UML), else the reason why not."""
    if native_vcan(name):
        return None
    reason = uml_unavailable_reason()
    if reason is None:
        return None
    return f"no SocketCAN here: interface {name} does not exist and User-Mode Linux is unusable: {reason}"


def default_env(extra: Mapping[str, str] | None = None) -> dict[str, str]:
    """The environment a job gets by default: this process's, plus headless MuJoCo and this venv on PATH."""
    env = dict(os.environ)
    env.setdefault("MUJOCO_GL", "egl")
    env.setdefault("PYTHONUNBUFFERED", "1")
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "/usr/sbin:/usr/bin:/sbin:/bin")])
    if "/usr/sbin" not in env["PATH"].split(os.pathsep):
        env["PATH"] += os.pathsep + "/usr/sbin:/sbin"
    env.pop("TMPDIR", None)  # the guest has its own /tmp
    if extra:
        env.update(extra)
    return env


#: Modules every boot loads: the CAN core, raw and broadcast-manager sockets, vcan.
BASE_MODULES = ("can", "can-raw", "can-bcm", "vcan")


def module_paths(names: Sequence[str], modules_dir: Path) -> list[Path]:
    """Absolute ``.ko`` paths for module ``names`` (e.g. ``"sch_tbf"``), dependencies first.

    Resolved through ``modules.dep`` of ``modules_dir``; raises UmlError for an unknown name.
    """
    deps: dict[str, list[str]] = {}
    for line in (modules_dir / "modules.dep").read_text().splitlines():
        target, _, rest = line.partition(":")
        deps[target] = rest.split()
    by_name = {Path(rel).name.removesuffix(".ko").replace("_", "-"): rel for rel in deps}
    order: list[str] = []

    def visit(rel: str) -> None:
        if rel in order:
            return
        for dep in reversed(deps.get(rel, [])):
            visit(dep)
        order.append(rel)

    for name in names:
        rel = by_name.get(name.replace("_", "-"))
        if rel is None:
            raise UmlError(f"kernel module {name!r} not found in {modules_dir}/modules.dep")
        visit(rel)
    return [modules_dir / rel for rel in order]


def _pick_cpu() -> int | None:
    try:
        cpus = sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return None
    return cpus[-1] if cpus else None


def run_in_uml(
    argv: Sequence[str],
    *,
    run_dir: Path,
    cwd: Path | None = None,
    env: Mapping[str, str] | None = None,
    vcans: Sequence[str] = ("vcan0",),
    fd: bool = True,
    txqueuelen: int | None = None,
    keep: Sequence[Path] = (),
    copy_back: Sequence[Path] = (),
    extra_modules: Sequence[str] = (),
    timeout: float = 300.0,
    mem: str = "1536M",
    cpu: int | None = None,
    on_output: Callable[[str, bytes], None] | None = None,
) -> UmlResult:
    """Boot UML, bring up ``vcans``, run ``argv`` there, power off, and return what it left.

    argv: the command (absolute paths or names on ``env['PATH']``), run as root inside.
    run_dir: an existing-or-creatable host folder; must be under ``/tmp`` or outside it (any path
        works); receives ``job.json``, ``init``, ``stdout.txt``, ``stderr.txt``, ``console.txt``,
        ``exit_status`` and ``init_error.txt`` on init failures.
    cwd: working directory inside (default: the repository root).
    env: the job's complete environment (default :func:`default_env`).
    vcans: SocketCAN interfaces to create and bring up; ``fd`` sets their MTU to 72 (CAN FD).
    txqueuelen: optional queue length for the vcans (a real ``can0`` has 10).
    extra_modules: more kernel modules to load by name, e.g. ``("sch_tbf",)`` for ``tc``.
    keep: further host folders under ``/tmp`` that the job must see (the guest's ``/tmp`` is
        a private tmpfs otherwise).
    copy_back: paths directly under ``/tmp`` (``/tmp/NAME``) that do not exist on the host: whatever
        the job left there in the guest's ``/tmp`` (a file or a whole folder) is copied to the host's
        when the job has ended (also at its timeout); one left alone, with a line on the job's stderr,
        when the host has one by then.
    timeout: seconds the job may run; it is then killed and ``returncode`` is 124. The whole
        UML process is killed ``BOOT_MARGIN_S`` later if it still has not powered off.
    mem: guest memory (``mem=``); cpu: the host CPU to pin UML to (default: the last allowed).
    on_output: called as ``on_output("stdout" | "stderr", data)`` with the job's output while it
        runs (from a thread; every byte once, in order per stream), e.g. to stream it to a terminal.

    Raises UmlError when UML is unavailable, the guest's init failed, or no exit status arrived.
    """
    reason = uml_unavailable_reason()
    if reason is not None:
        raise UmlError(reason)
    modules = uml_modules_dir()
    assert modules is not None
    run_dir = Path(run_dir).resolve()
    run_dir.mkdir(parents=True, exist_ok=True)
    for stale in ("exit_status", "init_error.txt", "stdout.txt", "stderr.txt"):
        (run_dir / stale).unlink(missing_ok=True)
    job = {
        "argv": list(argv),
        "cwd": str(cwd or REPO_ROOT),
        "env": dict(env if env is not None else default_env()),
        "run_dir": str(run_dir),
        # the checkout and its venv are always reachable, also when they live under /tmp (a CI clone)
        "keep": sorted({str(Path(str(k)).resolve()) for k in (*keep, REPO_ROOT, sys.prefix, cwd or REPO_ROOT)}),
        "copy_back": [str(Path(str(p))) for p in copy_back],
        "modules": [str(p) for p in module_paths([*BASE_MODULES, *extra_modules], modules)],
        "vcans": list(vcans),
        "mtu": CANFD_MTU if fd else CAN_MTU,
        "txqueuelen": txqueuelen,
        "timeout": timeout,
    }
    (run_dir / "job.json").write_text(json.dumps(job, indent=1))
    init = run_dir / "init"
    init.write_text(f"#!/bin/sh\nexec {sys.executable} -S {INIT_SCRIPT} {run_dir / 'job.json'}\n")
    init.chmod(0o755)
    umid = f"gs-{uuid.uuid4().hex[:12]}"
    uml_dir = run_dir / "uml"
    uml_dir.mkdir(exist_ok=True)
    cmd = [
        str(UML_KERNEL),
        f"mem={mem}",
        f"umid={umid}",
        f"uml_dir={uml_dir}",
        "root=/dev/root",
        "rootfstype=hostfs",
        "rootflags=/",
        "rw",
        "con=null",
        "con0=null,fd:1",
        f"init={init}",
    ]
    pin = cpu if cpu is not None else _pick_cpu()
    if pin is not None and shutil.which("taskset"):
        cmd = ["taskset", "-c", str(pin), *cmd]
    uml_env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "TMPDIR": str(uml_dir), "LD_PRELOAD": str(xstate_shim())}
    console_path = run_dir / "console.txt"
    start = time.monotonic()
    tail = _Tail(run_dir, on_output) if on_output is not None else None
    with open(console_path, "wb") as console:
        proc = subprocess.Popen(
            cmd, stdin=subprocess.DEVNULL, stdout=console, stderr=subprocess.STDOUT, env=uml_env, start_new_session=True
        )
        try:
            proc.wait(timeout=timeout + BOOT_MARGIN_S)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        finally:
            _kill_leftovers(proc.pid)
            shutil.rmtree(uml_dir, ignore_errors=True)
            if tail is not None:
                tail.finish()
    seconds = time.monotonic() - start
    console_text = console_path.read_text(errors="replace")
    status_file = run_dir / "exit_status"
    init_error = run_dir / "init_error.txt"
    if init_error.exists() and not (run_dir / "stdout.txt").exists():
        detail = init_error.read_text(errors="replace")
        last = next((ln.strip() for ln in reversed(detail.splitlines()) if ln.strip()), "no reason given")
        raise UmlError(f"UML init failed: {last}\n{detail}\n--- console (tail) ---\n{console_text[-3000:]}")
    if not status_file.exists():
        raise UmlError(
            f"UML gave no exit status after {seconds:.1f} s (timeout {timeout} s + {BOOT_MARGIN_S} s margin); "
            f"run dir {run_dir}\n--- console (tail) ---\n{console_text[-3000:]}"
        )
    return UmlResult(
        returncode=int(status_file.read_text().strip()),
        stdout=_read(run_dir / "stdout.txt"),
        stderr=_read(run_dir / "stderr.txt") + _read(init_error),
        console=console_text,
        run_dir=run_dir,
        seconds=seconds,
    )


class _Tail:
    """Follow ``stdout.txt`` and ``stderr.txt`` in ``run_dir`` while the guest writes them (a thread
    polling every 50 ms: the files are written by UML's host process through hostfs, and a poll
    is what ``tail -f`` does on files), handing new bytes to ``sink``; :meth:`finish` reads the rest."""

    POLL_S = 0.05

    def __init__(self, run_dir: Path, sink: Callable[[str, bytes], None]) -> None:
        self.sink = sink
        self.paths = {"stdout": run_dir / "stdout.txt", "stderr": run_dir / "stderr.txt"}
        self.offsets = {name: 0 for name in self.paths}
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="uml-output", daemon=True)
        self.thread.start()

    def _poll(self) -> None:
        for name, path in self.paths.items():
            try:
                with open(path, "rb") as f:
                    f.seek(self.offsets[name])
                    data = f.read()
            except FileNotFoundError:
                continue
            if data:
                self.offsets[name] += len(data)
                self.sink(name, data)

    def _run(self) -> None:
        while not self.stop.wait(self.POLL_S):
            self._poll()

    def finish(self) -> None:
        self.stop.set()
        self.thread.join()
        self._poll()


def _read(path: Path) -> str:
    try:
        return path.read_text(errors="replace")
    except FileNotFoundError:
        return ""


def _kill_leftovers(pgid: int) -> None:
    """UML's helper processes share its process group; make sure none outlives the run."""
    try:
        os.killpg(pgid, signal.SIGKILL)
    except ProcessLookupError:
        pass
