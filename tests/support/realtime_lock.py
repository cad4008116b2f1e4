"""Under pytest-xdist, tests marked ``realtime`` run one at a time, and the cores are theirs
first: the other workers wait between tests, or (background mode, below) go on at nice 19.

A realtime test's board runs on the wall clock (a control tick every 2 ms, a 200 ms watchdog) and
its host must keep up. On a 2-core machine two xdist workers already fill both cores; a third and
fourth process (the realtime test's host and board) then miss ticks: one late frame in four
two-worker runs of the whole suite, a watchdog hold right after connect in another. Lockstep boards
and pure tests do not care how slowly they run, so only the realtime ones are kept apart.

How: every test of a worker holds a ``flock`` on one file of the run (named by xdist's
``testrunuid``, shared by all workers of one run), shared for an ordinary test and exclusive for a
``realtime`` one, from its setup to its teardown (``pytest_runtest_protocol``). A turnstile lock
taken before the main one keeps a worker that starts test after test from starving a realtime test
that waits (the readers-writer pattern with a turnstile). The two lock files (empty) live in the
run's base temporary folder, the parent of every worker's ``--basetemp``, so pytest's own retention
of old runs removes them (no worker can tell when the others are done with them). Without xdist
(one process, a pytest started inside a test) nothing is locked.

A realtime test whose wall-clock part ends before the test does (a realtime recording followed by
lockstep replays, a board stopped for good whose loss the host is left to detect) calls
:func:`realtime_part_done`: from then on it holds the lock shared, so the other workers run their
ordinary tests beside the rest of it instead of idling to its end.

Where the worker may raise its nice value and lower it again (root, ``CAP_SYS_NICE`` or a large
enough ``RLIMIT_NICE``; Linux; below nice 19: :func:`background_possible`), the other workers need not idle at all (*background mode*): every ordinary test runs at nice 19,
with every process its worker has started, and a realtime test's worker moves its whole process tree
back to the nice value it started with for that test. Linux gives a nice-0 task ~68 times the CPU
share of a nice-19 one (weights 1 024 and 15, sched(7)) and lets it preempt one on wake-up, so the
realtime host and board find the cores nearly as free as when the others waited, while the ordinary
tests use what the realtime ones leave (~1.3 of 2 cores: 164 s of realtime tests used 108 CPU-s in
one run). Realtime tests still exclude one another (the main lock, exclusive only). Not the
``SCHED_IDLE`` class: idle-class tasks do not preempt one another on wake-up, so a lockstep host and
board waking each other every period waited out whole time slices (a run went at a third of its
speed). ``GHOSTSHELL_TESTS_REALTIME_ALONE`` set to anything but empty or ``0`` turns background mode off. So
does a worker that may not lower a nice value again (no root, no ``CAP_SYS_NICE``, ``RLIMIT_NICE``
too small) or that already runs at nice 19: realtime tests then run alone as above, and the suite
takes longer (12 min 9 s on two workers before background mode, n = 1). The run's header says
which mode it uses. An ordinary test that waits for what its subprocess does (a frame in a log, before
it sends a signal) polls through :func:`attentive`, at the base value: at nice 19, next to a realtime
board, the poller saw a fast lockstep run only after it had ended (CI, 2026-12-04).

Written here rather than taken from a plugin: pytest-xdist groups tests onto one worker
(``xdist_group``) but has no way to keep other workers idle meanwhile.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import resource
import sys
import tempfile
import threading
from collections.abc import Generator, Iterator
from pathlib import Path
from typing import IO

import pytest

MARKER = "realtime"
#: set to anything but empty or 0 (as GHOSTSHELL_ALL_TASKS): realtime tests run alone even where background mode
#: is possible
ALONE_ENV = "GHOSTSHELL_TESTS_REALTIME_ALONE"


def _tree(root: int) -> list[int]:
    """``root`` and every process below it (the parent field of each ``/proc/<pid>/stat``)."""
    children: dict[int, list[int]] = {}
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            with open(f"/proc/{entry.name}/stat", "rb") as f:
                stat = f.read()
        except OSError:  # gone meanwhile
            continue
        fields = stat[stat.rfind(b")") + 2:].split()  # after "pid (comm) ": state, ppid, ...
        if len(fields) > 1:
            children.setdefault(int(fields[1]), []).append(int(entry.name))
    found, todo = [], [root]
    while todo:
        pid = todo.pop()
        found.append(pid)
        todo.extend(children.get(pid, ()))
    return found


#: the nice value of an ordinary test's process tree in background mode (the weakest)
BACKGROUND_NICE = 19


def set_tree_nice(root: int, nice: int) -> None:
    """Give every thread of ``root`` and of each process below it the nice value ``nice`` (Linux keeps
    one per thread; ``setpriority(PRIO_PROCESS, tid)``). The tree is scanned again until a scan finds no
    thread it has not set (at most 5 scans): a process or thread started meanwhile by one not yet
    changed is changed too. Processes and threads that end meanwhile, or that may not be changed
    (another user's), are left alone; a process that left the tree (a daemon that double-forked) is
    not found."""
    done: set[int] = set()
    for _ in range(5):
        new = False
        for pid in _tree(root):
            try:
                tids = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
            except OSError:
                continue
            for tid in tids:
                if tid in done:
                    continue
                done.add(tid)
                new = True
                try:
                    os.setpriority(os.PRIO_PROCESS, tid, nice)
                except (ProcessLookupError, PermissionError):
                    pass
        if not new:
            return


#: CAP_SYS_NICE's bit in /proc/PID/status's CapEff (linux/capability.h)
CAP_SYS_NICE = 23


def _may_lower_nice_to(nice: int) -> bool:
    """True if this process may set a nice value as low as ``nice``: ``CAP_SYS_NICE`` in its effective
    set, or a soft ``RLIMIT_NICE`` that allows it (the limit ``r`` allows down to ``20 - r``). Asks
    without changing anything."""
    try:
        with open("/proc/self/status") as f:
            caps = next((line.split()[1] for line in f if line.startswith("CapEff:")), "0")
        if int(caps, 16) >> CAP_SYS_NICE & 1:
            return True
    except (OSError, ValueError):
        pass
    soft, _hard = resource.getrlimit(resource.RLIMIT_NICE)
    return soft == resource.RLIM_INFINITY or 20 - soft <= nice


def background_possible(env: dict[str, str] | None = None) -> bool:
    """True if background mode can work here: Linux (``/proc``), ``$GHOSTSHELL_TESTS_REALTIME_ALONE`` is
    empty or ``0``, this process runs below :data:`BACKGROUND_NICE` (a realtime test must be able to rank
    above the rest) and may come back to its nice value from there (root or ``CAP_SYS_NICE``, or
    ``RLIMIT_NICE``; otherwise lowering a nice value is refused). Changes nothing."""
    if (os.environ if env is None else env).get(ALONE_ENV, "").strip() not in ("", "0"):
        return False
    if not sys.platform.startswith("linux") or not os.path.isdir("/proc/self/task"):
        return False
    nice = os.getpriority(os.PRIO_PROCESS, 0)
    return nice < BACKGROUND_NICE and _may_lower_nice_to(nice)


class _RunLock:
    """The run's readers-writer lock: ``hold(exclusive)`` around one test."""

    def __init__(self, run_id: str, base: Path, background: bool = False, base_nice: int = 0) -> None:
        #: background mode (module docstring): ordinary tests take no lock and run at nice 19
        self.background = background
        #: the nice value a realtime test's process tree runs at in background mode
        self.base_nice = base_nice
        self._main: IO[bytes] = open(base / f"ghostshell-pytest-{run_id}.lock", "ab")  # noqa: SIM115 - held for the session
        self._turn: IO[bytes] = open(base / f"ghostshell-pytest-{run_id}.turn", "ab")  # noqa: SIM115

        self._exclusive_held = False
        self._keep = False

    @contextlib.contextmanager
    def hold(self, exclusive: bool, keep: bool = False) -> Iterator[None]:
        """Hold the lock around one test; ``keep``: an exclusive holder whose next test is realtime
        too keeps it (the other workers would otherwise start a long test in between)."""
        if self.background:
            with self._hold_background(exclusive):
                yield
            return
        main, turn = self._main.fileno(), self._turn.fileno()
        if not (exclusive and self._exclusive_held):
            fcntl.flock(turn, fcntl.LOCK_EX)  # wait behind a realtime test that is waiting for the main lock
            if exclusive:
                fcntl.flock(main, fcntl.LOCK_EX)
                fcntl.flock(turn, fcntl.LOCK_UN)
            else:
                fcntl.flock(turn, fcntl.LOCK_UN)
                fcntl.flock(main, fcntl.LOCK_SH)
        self._exclusive_held = exclusive
        self._keep = exclusive and keep
        try:
            yield
        finally:
            if not (exclusive and keep):
                fcntl.flock(main, fcntl.LOCK_UN)
                self._exclusive_held = False

    @contextlib.contextmanager
    def _hold_background(self, exclusive: bool) -> Iterator[None]:
        """Background mode: an ordinary test runs as it is (at nice 19); a realtime one waits for any
        other realtime test, then runs with this worker's process tree at the base nice value."""
        if not exclusive:
            yield
            return
        fcntl.flock(self._main.fileno(), fcntl.LOCK_EX)
        self._exclusive_held = True
        try:
            set_tree_nice(os.getpid(), self.base_nice)
            yield
        finally:
            self._release_background()

    def _release_background(self) -> bool:
        """Back to nice 19, then let the next realtime test start; False if nothing was held."""
        if not self._exclusive_held:
            return False
        try:
            set_tree_nice(os.getpid(), BACKGROUND_NICE)
        finally:
            fcntl.flock(self._main.fileno(), fcntl.LOCK_UN)
            self._exclusive_held = False
        return True

    def share(self) -> bool:
        """Trade the exclusive lock this worker holds for a shared one, until its test ends; True if it did.

        Kept instead (to the end of the test, as without this call) when this worker's next test is
        realtime too (:meth:`hold`'s ``keep``: another worker's long test would start in between), or
        while a realtime test of another worker waits for the lock (it holds the turnstile): flock
        converts a lock by dropping it and then taking the new one, so that waiter would start between
        the two, beside the rest of this test. Holding the turnstile across the conversion keeps a
        realtime test that comes later out until it is done; ordinary tests waiting for the main lock
        start at once.

        In background mode the rest of the test runs at nice 19 and the next realtime test may start:
        True if this worker held the realtime lock."""
        if self.background:
            return self._release_background()
        if not self._exclusive_held or self._keep:
            return False
        try:
            fcntl.flock(self._turn.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:  # a realtime test is waiting for the main lock
            return False
        try:
            fcntl.flock(self._main.fileno(), fcntl.LOCK_SH)  # never waits: only shared requests can be queued
        finally:
            fcntl.flock(self._turn.fileno(), fcntl.LOCK_UN)
        self._exclusive_held = False
        return True

    def close(self) -> None:
        self._main.close()
        self._turn.close()


_lock: _RunLock | None = None


def realtime_part_done() -> bool:
    """Called by a ``realtime`` test once no board of its own runs on the wall clock any more (its realtime
    run has ended, or its board is stopped for good): the other workers may start ordinary tests beside
    what is left of it (lockstep replays, rendering, checks), which needs no core to itself. Best effort
    (:meth:`_RunLock.share`): True if the lock is now shared (in background mode: released, and the rest
    of the test runs at nice 19); a no-op without xdist or in an ordinary test."""
    return _lock is not None and _lock.share()


@contextlib.contextmanager
def attentive() -> Iterator[None]:
    """The calling thread at the worker's base nice value for the block, then back where it was: for a
    test that *waits* for something a subprocess does (:func:`support.cliproc.wait_until` polling a
    frame log before it sends a signal). In background mode an ordinary test runs at nice 19; a
    waiting thread on the same core as a realtime test's board (nice 0 or lower) then gets well
    under 1 % of that core and may see a lockstep run only after it ended. Only this thread moves
    (``setpriority`` on its thread id), so the subprocesses it watches stay at 19. A no-op outside
    background mode, in a realtime test (already at the base value) and when the value cannot be set."""
    lock = _lock
    if lock is None or not lock.background or lock._exclusive_held:
        yield
        return
    tid = threading.get_native_id()
    before = os.getpriority(os.PRIO_PROCESS, tid)
    try:
        os.setpriority(os.PRIO_PROCESS, tid, lock.base_nice)
    except OSError:
        yield
        return
    try:
        yield
    finally:
        os.setpriority(os.PRIO_PROCESS, tid, before)


def _run_dir(config: pytest.Config) -> Path:
    """The folder all workers of this run share: xdist hands each worker ``<run's basetemp>/<worker
    id>`` as its ``--basetemp`` (the system temp dir if a worker somehow has none)."""
    basetemp = getattr(config.option, "basetemp", None)
    return Path(basetemp).parent if basetemp else Path(tempfile.gettempdir())


def pytest_configure(config: pytest.Config) -> None:
    global _lock
    config.addinivalue_line("markers", f"{MARKER}: runs a board on the wall clock; under xdist it runs alone or "
                                       "beside nice-19 tests "
                                       "(tests/support/realtime_lock.py)")
    workerinput = getattr(config, "workerinput", None)  # set only inside an xdist worker
    if workerinput is not None and os.name == "posix":
        background = background_possible()
        _lock = _RunLock(str(workerinput["testrunuid"]), _run_dir(config), background,
                         os.getpriority(os.PRIO_PROCESS, 0))
        if background:
            set_tree_nice(os.getpid(), BACKGROUND_NICE)


def pytest_report_header(config: pytest.Config) -> str:
    """One header line: how realtime tests run (the workers inherit this process's nice value and rights)."""
    if background_possible():
        return f"realtime tests: one at a time, the others beside them at nice {BACKGROUND_NICE} (background mode)"
    return ("realtime tests: alone under xdist (background mode off: needs Linux, the right to lower a nice value "
            f"again, a nice value below {BACKGROUND_NICE}, and ${ALONE_ENV} empty or 0)")


def pytest_unconfigure(config: pytest.Config) -> None:
    global _lock
    if _lock is not None:
        _lock.close()
        _lock = None


@pytest.hookimpl(hookwrapper=True, tryfirst=True)  # outermost: the wait is not charged to a test's timeout
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Generator[None, None, None]:
    if _lock is None:
        yield
        return
    exclusive = item.get_closest_marker(MARKER) is not None
    keep = exclusive and nextitem is not None and nextitem.get_closest_marker(MARKER) is not None
    with _lock.hold(exclusive, keep):
        yield
