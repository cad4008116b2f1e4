"""The board's per-tick servo path in C (``tick.c``), built on first use and loaded with ctypes.

Why: a lockstep tick is MuJoCo's ``mj_step`` plus the board's own per-tick work (interpolation, the
servo model, writing ctrl). In Python that work cost ~20 µs per tick for a 12-servo robot, more
than ``mj_step`` itself for a robot standing still (~15 µs); in C it is well under a microsecond
plus one ctypes call. ``gs_run`` / :meth:`NativeTick.run` runs several ticks per call: the board's
Python around a tick (safety, jitter buffer, reports; ~5 µs) then runs once per batch of quiet ticks
(:meth:`firmware_sim.board.Board.run`). The C does the same IEEE double operations in the same order as the Python
reference (:meth:`firmware_sim.board_stream.TargetStream.interpolate`, :meth:`firmware_sim.servo_model.ServoModel.step_list`),
so the board's state is bit-identical whichever runs (``tests/firmware/test_native_tick.py`` compares
both tick by tick over long random streams). ``mj_step`` is called from C through a function pointer
into the ``libmujoco`` the mujoco wheel ships (the one the Python bindings already loaded), on the
``mjModel``/``mjData`` addresses the bindings expose (``MjModel._address``, ``MjData._address``).

Overlap: :meth:`NativeTick.run_during` runs a batch on a thread of the C library's own (``gs_worker_*`` in
``tick.c``, POSIX threads; it runs no Python, so the GIL stays free) while the caller's thread does other
work: the lockstep server encodes and writes the last reports and reads what came meanwhile
(:meth:`firmware_sim.board.Board.run`, :meth:`firmware_sim.server.BoardServer._link_work`). The same gs_run
on the same state: the ticks are bit-identical; only nothing else may touch the board's arrays or MjData
until the batch is waited for. One thread per board, made on first use, ended by :meth:`NativeTick.close`
(the server calls it when it stops).

Which runs: :func:`firmware_sim.config.kernel_choice` reads ``$GHOSTSHELL_BOARD_KERNEL``: ``native`` (the
default: C when a C compiler is installed and the build loads, else the Python path with a one-line note
on stderr, once per process), ``python`` (the reference), ``native!`` (C or :class:`NativeUnavailable`;
tests use it). ``BoardConfig.kernel`` overrides the variable. Whatever goes wrong building or loading
(no compiler, a compiler error, a stale or corrupt cached library, another libmujoco) only selects the
Python path: it never stops a board. The build is warning-clean under ``-Werror`` (a test checks);
the runtime build does not pass ``-Werror``, so a newer compiler's new warning cannot disable the C.

Wire input never reaches the C as an index: the servo count, ``qpos``/``ctrl`` addresses and limits
come from the model; wire values arrive as doubles already bounded by the codec (Q16 targets, no NaN)
and the board's admission checks (apply-at within ``max_future_us``), so the C only does arithmetic on them.

Written by hand rather than with cffi or a setuptools extension: the project installs editable from
a fresh clone with no build step, and ctypes needs neither Python headers nor another dependency;
the build follows :mod:`firmware_sim.cfirmware.build` (a cache folder keyed by a SHA-256 of the
source, the flags and the compiler; written to a temporary name and renamed into place).

A MuJoCo fatal error (``mju_error``) inside a native ``mj_step`` ends the process through MuJoCo's
handler instead of raising ``mujoco.FatalError``; with the Python path that exception ends the board
too (nothing catches it), so only the message's form differs.

MuJoCo's stage timers (``MjData.timer``) read the system clock twice per stage, ~30 times per
``mj_step`` (~1 µs of a ~21 µs CoCo step); the board never reads them. When the library loads, MuJoCo's
timer callback ``mjcb_time`` (process-wide) is set to ``gs_no_clock`` (returns 0: every timer reads 0)
unless another callback is already installed or ``$GHOSTSHELL_MJ_TIMERS=1`` (keep them, for profiling
with ``MjData.timer``). The physics does not depend on them (trajectories bit-identical either way).

Cache folder: ``$GHOSTSHELL_NATIVE_CACHE`` or the user cache dir (platformdirs) ``/native``.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np
import platformdirs

from firmware_sim.config import KERNEL_ENV, kernel_choice

__all__ = ["FLAGS", "GS_CAP", "GS_INTERP", "KERNEL_ENV", "TIMERS_ENV", "NativeTick", "NativeUnavailable", "TickState",
           "build", "cache_root", "kernel_choice", "load", "native_reason", "note_fallback"]

SOURCE = Path(__file__).with_name("tick.c")
#: -ffp-contract=off and no -ffast-math keep the C's double operations those of the Python reference
FLAGS = ("-std=c99", "-O2", "-fPIC", "-shared", "-pthread", "-ffp-contract=off", "-fno-fast-math", "-Wall", "-Wextra")
GS_INTERP = 1
GS_CAP = 2
#: ``1`` keeps MuJoCo's stage timers (``MjData.timer``) running in a process that loads the C tick
TIMERS_ENV = "GHOSTSHELL_MJ_TIMERS"

_ptr_t = ctypes.c_void_p  # every array pointer (int64_t* / double* in tick.c: the same ABI)


class NativeUnavailable(RuntimeError):
    """The C tick cannot be built or loaded here (message: why, e.g. no C compiler)."""


class TickState(ctypes.Structure):
    """Mirror of ``gs_tick_state`` in tick.c (every field 8 bytes, same order).

    Array pointers are plain addresses (``c_void_p`` set from ``ndarray.ctypes.data``): numpy's
    ``data_as`` (a ``ctypes.cast``) left ~350 B per board on the heap (tests/fuzz/test_fuzz_memory.py)."""

    _fields_ = [
        ("n", ctypes.c_int64), ("substeps", ctypes.c_int64),
        ("model", ctypes.c_void_p), ("data", ctypes.c_void_p), ("mj_step", ctypes.c_void_p),
        ("qpos", _ptr_t), ("mj_ctrl", _ptr_t), ("qpos_adr", _ptr_t), ("act_id", _ptr_t),
        ("anchor_t", _ptr_t), ("anchor_v", _ptr_t), ("next_ok", _ptr_t), ("next_t", _ptr_t), ("next_v", _ptr_t),
        ("desired", _ptr_t), ("ctrl", _ptr_t), ("cmd", _ptr_t),
        ("mins", _ptr_t), ("maxs", _ptr_t), ("max_step", _ptr_t), ("max_speed", _ptr_t),
        ("period_s", ctypes.c_double), ("resolution", ctypes.c_double), ("deadband", ctypes.c_double),
        ("limit_clamps", ctypes.c_int64), ("speed_clamps", ctypes.c_int64),
    ]


class GsCopy(ctypes.Structure):
    """Mirror of ``gs_copy`` in tick.c: ``n`` doubles from ``src`` to ``dst`` (addresses)."""

    _fields_ = [("dst", ctypes.c_void_p), ("src", ctypes.c_void_p), ("n", ctypes.c_int64)]


class GsPending(ctypes.Structure):
    """Mirror of ``gs_pending`` in tick.c: the anchors and next keyframes (per servo) of a split run's second part."""

    _fields_ = [("anchor_t", _ptr_t), ("anchor_v", _ptr_t), ("next_ok", _ptr_t), ("next_t", _ptr_t), ("next_v", _ptr_t)]


def cache_root() -> Path:
    """Where built libraries are kept: ``$GHOSTSHELL_NATIVE_CACHE``, else the user cache dir's ``native``."""
    env = os.environ.get("GHOSTSHELL_NATIVE_CACHE")
    return Path(env) if env else Path(platformdirs.user_cache_dir("ghostshell")) / "native"


def _compiler() -> str:
    cc = shutil.which(os.environ.get("CC") or "cc")
    if cc is None:
        raise NativeUnavailable(f"no C compiler ({os.environ.get('CC') or 'cc'}) found; "
                                "install one with: apt-get install -y gcc libc6-dev")
    return cc


def build(rebuild: bool = False) -> Path:
    """Compile tick.c into the cache (unless there already, or ``rebuild``); returns the library's path.

    The file name is a SHA-256 of the source, :data:`FLAGS`, the compiler (path, size, mtime) and the
    platform. Raises :class:`NativeUnavailable` (no compiler, or the compiler's last lines) or ``OSError``."""
    cc = _compiler()
    text = SOURCE.read_bytes()
    st = os.stat(cc)
    ident = (FLAGS, os.path.realpath(cc), st.st_size, st.st_mtime_ns, sys.platform, platform.machine())
    key = hashlib.sha256(text + repr(ident).encode()).hexdigest()[:16]
    out = cache_root() / f"tick-{key}.so"
    if out.is_file() and not rebuild:
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=".tick-", suffix=".so", dir=out.parent)
    os.close(fd)
    try:
        r = subprocess.run([cc, *FLAGS, str(SOURCE), "-o", tmp_name, "-lm"], capture_output=True, text=True, timeout=120)
        if r.returncode != 0:
            tail = " | ".join((r.stdout + r.stderr).strip().splitlines()[-5:])
            raise NativeUnavailable(f"building {SOURCE.name} with {cc} failed (exit {r.returncode}): {tail}")
        os.replace(tmp_name, out)  # atomic: parallel processes never load a half-written library
    finally:
        if os.path.exists(tmp_name):
            os.unlink(tmp_name)
    return out


_lock = threading.Lock()
_loaded: tuple[ctypes.CDLL, int] | None = None
_failure: str | None = None
_noted = False


def _libmujoco() -> ctypes.CDLL:
    folder = Path(mujoco.__file__).parent
    found = sorted(folder.glob("libmujoco.so*")) + sorted(folder.glob("libmujoco*.dylib"))
    if not found:
        raise NativeUnavailable(f"no libmujoco shared library next to {mujoco.__file__}")
    lib = ctypes.CDLL(str(found[0]))  # already loaded by the bindings: the same library, the same globals
    lib.mj_versionString.restype = ctypes.c_char_p
    theirs, ours = lib.mj_versionString().decode(), mujoco.mj_versionString()
    if theirs != ours:
        raise NativeUnavailable(f"{found[0].name} is MuJoCo {theirs}, the bindings run {ours}")
    return lib


def _open(path: Path) -> ctypes.CDLL:
    lib = ctypes.CDLL(str(path))
    fn = lib.gs_tick
    fn.argtypes = [ctypes.c_void_p, ctypes.c_int64, ctypes.c_int64, ctypes.c_double]
    fn.restype = ctypes.c_int
    lib.gs_no_clock.restype = ctypes.c_double
    run = lib.gs_run
    run.argtypes = [ctypes.c_void_p, ctypes.c_int64, ctypes.c_int64, ctypes.c_int64, ctypes.c_int64, ctypes.c_double]
    run.restype = ctypes.c_int64
    lib.gs_worker_new.argtypes = []
    lib.gs_worker_new.restype = ctypes.c_void_p
    lib.gs_worker_start.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int64, ctypes.c_int64, ctypes.c_int64,
                                    ctypes.c_int64, ctypes.c_double]
    lib.gs_worker_start.restype = None
    split = lib.gs_run_split
    split.argtypes = [ctypes.c_void_p, ctypes.c_int64, ctypes.c_int64, ctypes.c_int64, ctypes.c_int64, ctypes.c_int64,
                      ctypes.c_double, ctypes.c_void_p, ctypes.c_int64, ctypes.c_void_p, ctypes.c_void_p]
    split.restype = ctypes.c_int64
    lib.gs_worker_start_split.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int64, ctypes.c_int64,
                                          ctypes.c_int64, ctypes.c_int64, ctypes.c_int64, ctypes.c_double,
                                          ctypes.c_void_p, ctypes.c_int64, ctypes.c_void_p]
    lib.gs_worker_start_split.restype = None
    lib.gs_worker_wait_split.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
    lib.gs_worker_wait_split.restype = ctypes.c_int64
    lib.gs_worker_wait.argtypes = [ctypes.c_void_p]
    lib.gs_worker_wait.restype = ctypes.c_int64
    lib.gs_worker_free.argtypes = [ctypes.c_void_p]
    lib.gs_worker_free.restype = None
    return lib


def load() -> tuple[ctypes.CDLL, int]:
    """The loaded kernel library and the address of ``mj_step`` (cached per process)."""
    global _loaded, _failure
    with _lock:
        if _loaded is not None:
            return _loaded
        if _failure is not None:
            raise NativeUnavailable(_failure)
        try:
            path = build()
            try:
                lib = _open(path)
            except (OSError, AttributeError):  # a corrupt or foreign file under our name: build it again
                lib = _open(build(rebuild=True))
            step = ctypes.cast(_libmujoco().mj_step, ctypes.c_void_p).value
            if not step:
                raise NativeUnavailable("libmujoco has no mj_step")
            _loaded = (lib, step)
            _quiet_timers(lib)
            return _loaded
        except Exception as e:  # noqa: BLE001 - whatever it is, the board runs the Python path instead
            _failure = str(e) if isinstance(e, NativeUnavailable) else f"{type(e).__name__}: {e}"
            raise NativeUnavailable(_failure) from None


_no_clock: object = None  # the ctypes function object MuJoCo holds (kept alive here)


def _quiet_timers(lib: ctypes.CDLL) -> None:
    """Stop MuJoCo's stage timers (``mjcb_time`` := ``gs_no_clock``) unless $GHOSTSHELL_MJ_TIMERS=1 or a
    timer callback is already installed (see the module docstring)."""
    global _no_clock
    if os.environ.get(TIMERS_ENV) == "1" or mujoco.get_mjcb_time() is not None:
        return
    _no_clock = ctypes.cast(lib.gs_no_clock, ctypes.CFUNCTYPE(ctypes.c_double))
    mujoco.set_mjcb_time(_no_clock)


def native_reason() -> str | None:
    """Why the native kernel is unavailable (None when it loads)."""
    try:
        load()
    except NativeUnavailable as e:
        return str(e)
    return None


def note_fallback(reason: str) -> None:
    """One stderr line per process: the board runs the Python path because the C one is unavailable."""
    global _noted
    if not _noted:
        _noted = True
        print(f"board: native tick unavailable ({reason}); running the Python reference path", file=sys.stderr)


def _ptr(a: np.ndarray) -> int:
    """The address of ``a``'s first element (the caller keeps ``a`` alive)."""
    return int(a.__array_interface__["data"][0])


class NativeTick:
    """The C tick bound to one board's arrays (which must stay allocated as long as this lives).

    ``arrays``: ``anchor_t``/``next_ok``/``next_t`` int64, ``anchor_v``/``next_v``/``desired``/``ctrl``/``cmd``/
    ``mins``/``maxs``/``max_step``/``max_speed`` float64, ``qpos_adr``/``act_id`` int64, one per servo.
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, substeps: int, period_s: float,
                 resolution: float, deadband: float, arrays: dict[str, np.ndarray]) -> None:
        lib, step = load()
        self._keep = arrays  # the C holds raw pointers into these
        self._model, self._data = model, data
        s = TickState()
        s.n = len(arrays["cmd"])
        s.substeps = int(substeps)
        s.model, s.data, s.mj_step = model._address, data._address, step
        s.qpos = _ptr(data.qpos)
        s.mj_ctrl = _ptr(data.ctrl)
        for names, dtype in ((("qpos_adr", "act_id", "anchor_t", "next_ok", "next_t"), np.int64),
                             (("anchor_v", "next_v", "desired", "ctrl", "cmd", "mins", "maxs", "max_step",
                               "max_speed"), np.float64)):
            for name in names:
                a = arrays[name]
                if a.dtype != dtype or not a.flags.c_contiguous or len(a) != s.n:
                    raise ValueError(f"{name}: need {s.n} contiguous {np.dtype(dtype)}, got {len(a)} {a.dtype}")
                setattr(s, name, _ptr(a))
        # the C indexes qpos and ctrl with these: check them here, once
        if s.n and not (0 <= int(arrays["qpos_adr"].min()) and int(arrays["qpos_adr"].max()) < model.nq
                        and 0 <= int(arrays["act_id"].min()) and int(arrays["act_id"].max()) < model.nu):
            raise ValueError("qpos_adr/act_id outside the model's qpos/ctrl")
        if data.qpos.dtype != np.float64 or data.ctrl.dtype != np.float64:
            raise ValueError("MjData qpos/ctrl are not float64")
        s.period_s, s.resolution, s.deadband = float(period_s), float(resolution), float(deadband)
        self.state = s
        self._addr = ctypes.addressof(s)
        self._fn = lib.gs_tick
        self._run = lib.gs_run
        self._lib = lib
        #: a split run's second part's anchors and next keyframes (:meth:`run_split_during`; the caller fills them)
        n = int(s.n)
        self.pending: dict[str, np.ndarray] = {
            "anchor_t": np.zeros(n, np.int64), "anchor_v": np.zeros(n, np.float64), "next_ok": np.zeros(n, np.int64),
            "next_t": np.zeros(n, np.int64), "next_v": np.zeros(n, np.float64)}
        p = GsPending()
        for name, a in self.pending.items():
            setattr(p, name, _ptr(a))
        self._pending = p
        self._pending_addr = ctypes.addressof(p)
        self._copies = (GsCopy * 8)()
        self._copies_addr = ctypes.addressof(self._copies)
        self._copy_offsets: list[int] = []
        self._clamped2 = ctypes.c_int64(0)
        self._clamped2_addr = ctypes.addressof(self._clamped2)
        self._worker: int | None = None  # gs_worker_new's handle once :meth:`run_during` first ran
        self._no_worker = False  # the C could not start a thread: run_during runs in this thread
        self._worker_pid = 0  # the process that made the thread

    def _ensure_worker(self) -> int | None:
        """The kernel's worker thread (made on first use), or None where the C could not make one."""
        if self._worker is not None and self._worker_pid != os.getpid():
            self._worker = None  # a forked child: the thread stayed in the parent (its handle is the parent's)
        if self._worker is None and not self._no_worker:
            self._worker = self._lib.gs_worker_new() or None
            self._no_worker = self._worker is None
            self._worker_pid = os.getpid()
        return self._worker

    def run_during(self, t: int, n: int, tick_us: int, flags: int, during: Callable[[], object]) -> int:
        """:meth:`run` on the kernel's own thread while ``during()`` runs in this one (the GIL is free
        meanwhile: the C thread runs no Python), then wait for the ticks; returns as :meth:`run`.

        ``during`` must not touch this board's arrays or its MjData (they are the ticks' state). When it
        raises, the ticks are still waited for before the exception goes on. Without a thread (the C
        could not make one) ``during()`` runs first, then the ticks, in this thread."""
        if self._ensure_worker() is None:
            during()
            return self.run(t, n, tick_us, flags)
        self._lib.gs_worker_start(self._worker, self._addr, t, n, tick_us, flags, 0.0)
        try:
            during()
        finally:
            clamped = int(self._lib.gs_worker_wait(self._worker))
        return clamped

    def set_snapshot(self, regions: list[tuple[int, int, int]]) -> None:
        """What :meth:`run_split_during` copies between its parts: (offset in its ``dst`` buffer (doubles),
        source address, doubles) each (at most 8; :meth:`firmware_sim.board_reports.BoardReports.snapshot_regions`).
        The sources must stay allocated as long as this lives (the board's ``MjData``)."""
        if len(regions) > len(self._copies):
            raise ValueError(f"at most {len(self._copies)} snapshot regions, got {len(regions)}")
        for k, (_, src, n) in enumerate(regions):
            self._copies[k].src, self._copies[k].n = src, n
        self._copy_offsets = [off for off, _, _ in regions]

    def _run_split(self, t: int, n1: int, n2: int, tick_us: int, flags: int, ncopy: int) -> tuple[int, int]:
        c1 = int(self._lib.gs_run_split(self._addr, t, n1, n2, tick_us, flags, 0.0, self._copies_addr, ncopy,
                                        self._pending_addr, self._clamped2_addr))
        return c1, int(self._clamped2.value)

    def run_split_during(self, t: int, n1: int, n2: int, tick_us: int, flags: int, dst: np.ndarray,
                         during: Callable[[], object]) -> tuple[int, int]:
        """Two batches in one job, as :meth:`run_during` runs one: ``n1`` ticks from ``t``; then the regions
        of :meth:`set_snapshot` copied into ``dst`` (float64, contiguous, long enough; the caller keeps it);
        then :attr:`pending` (the anchors and next keyframes the first tick of the second part sees, as the
        board's ``_apply_due`` and ``refresh_next`` would leave them) copied over the state's arrays; then
        ``n2`` ticks from ``t + n1 * tick_us``. Returns each part's clamped ticks. The same state as
        ``run(t, n1, ...)``, the copies, ``run(t + n1 * tick_us, n2, ...)`` in turn."""
        base = _ptr(dst)
        copies = self._copies
        for k, off in enumerate(self._copy_offsets):
            copies[k].dst = base + 8 * off
        ncopy = len(self._copy_offsets)
        if self._ensure_worker() is None:
            during()
            return self._run_split(t, n1, n2, tick_us, flags, ncopy)
        self._lib.gs_worker_start_split(self._worker, self._addr, t, n1, n2, tick_us, flags, 0.0, self._copies_addr,
                                        ncopy, self._pending_addr)
        try:
            during()
        finally:
            c1 = int(self._lib.gs_worker_wait_split(self._worker, self._clamped2_addr))
        return c1, int(self._clamped2.value)

    def close(self) -> None:
        """End the kernel's thread, if :meth:`run_during` started one (idempotent)."""
        worker, self._worker = self._worker, None
        if worker is not None and self._worker_pid == os.getpid():
            self._lib.gs_worker_free(worker)

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown: the library may be gone
            pass

    def tick(self, t: int, flags: int, cap: float = 0.0) -> bool:
        """One tick at board time ``t`` (µs); ``flags``: :data:`GS_INTERP` | :data:`GS_CAP`. True if clamped."""
        return bool(self._fn(self._addr, t, flags, cap))

    def run(self, t: int, n: int, tick_us: int, flags: int, cap: float = 0.0) -> int:
        """``n`` ticks at board times ``t``, ``t + tick_us``, ... (µs), each exactly :meth:`tick` with
        ``flags``; returns how many of them clamped a servo."""
        return int(self._run(self._addr, t, n, tick_us, flags, cap))

    @property
    def limit_clamps(self) -> int:
        return int(self.state.limit_clamps)

    @property
    def speed_clamps(self) -> int:
        return int(self.state.speed_clamps)
