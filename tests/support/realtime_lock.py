"""Under pytest-xdist, a test marked ``realtime`` runs alone: the other workers wait between tests.

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

Written here rather than taken from a plugin: pytest-xdist groups tests onto one worker
(``xdist_group``) but has no way to keep other workers idle meanwhile.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import tempfile
from collections.abc import Generator, Iterator
from pathlib import Path
from typing import IO

import pytest

MARKER = "realtime"


class _RunLock:
    """The run's readers-writer lock: ``hold(exclusive)`` around one test."""

    def __init__(self, run_id: str, base: Path) -> None:
        self._main: IO[bytes] = open(base / f"ghostshell-pytest-{run_id}.lock", "ab")  # noqa: SIM115 - held for the session
        self._turn: IO[bytes] = open(base / f"ghostshell-pytest-{run_id}.turn", "ab")  # noqa: SIM115

        self._exclusive_held = False
        self._keep = False

    @contextlib.contextmanager
    def hold(self, exclusive: bool, keep: bool = False) -> Iterator[None]:
        """Hold the lock around one test; ``keep``: an exclusive holder whose next test is realtime
        too keeps it (the other workers would otherwise start a long test in between)."""
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

    def share(self) -> bool:
        """Trade the exclusive lock this worker holds for a shared one, until its test ends; True if it did.

        Kept instead (to the end of the test, as without this call) when this worker's next test is
        realtime too (:meth:`hold`'s ``keep``: another worker's long test would start in between), or
        while a realtime test of another worker waits for the lock (it holds the turnstile): flock
        converts a lock by dropping it and then taking the new one, so that waiter would start between
        the two, beside the rest of this test. Holding the turnstile across the conversion keeps a
        realtime test that comes later out until it is done; ordinary tests waiting for the main lock
        start at once."""
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
    (:meth:`_RunLock.share`): True if the lock is now shared; a no-op without xdist or in an ordinary test."""
    return _lock is not None and _lock.share()


def _run_dir(config: pytest.Config) -> Path:
    """The folder all workers of this run share: xdist hands each worker ``<run's basetemp>/<worker
    id>`` as its ``--basetemp`` (the system temp dir if a worker somehow has none)."""
    basetemp = getattr(config.option, "basetemp", None)
    return Path(basetemp).parent if basetemp else Path(tempfile.gettempdir())


def pytest_configure(config: pytest.Config) -> None:
    global _lock
    config.addinivalue_line("markers", f"{MARKER}: runs a board on the wall clock; under xdist it runs alone "
                                       "(tests/support/realtime_lock.py)")
    workerinput = getattr(config, "workerinput", None)  # set only inside an xdist worker
    if workerinput is not None and os.name == "posix":
        _lock = _RunLock(str(workerinput["testrunuid"]), _run_dir(config))


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
