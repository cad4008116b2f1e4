"""The suite's readers-writer lock (tests/support/realtime_lock.py): a realtime test holds the run's
lock exclusively, so another worker can neither start a test beside it nor pass the turnstile while
it waits; ordinary tests share it. In background mode ordinary tests take no lock and run at nice
19, and a realtime test's process tree at the worker's first nice value. Real flocks and nice values
of real processes, synchronised on pipes."""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys
import uuid
from pathlib import Path
from types import SimpleNamespace

import pytest

from support.realtime_lock import BACKGROUND_NICE, _may_lower_nice_to, _RunLock, _run_dir, background_possible, set_tree_nice

HOLDER = """
import sys
sys.path.insert(0, {tests!r})
from pathlib import Path
from support.realtime_lock import _RunLock
lock = _RunLock({run!r}, Path({base!r}))
with lock.hold({exclusive}):
    print("held", flush=True)
    sys.stdin.readline()
"""


#: a realtime test that calls realtime_part_done() (its lock's share()) once told to: prints what came of it
SHARER = """
import sys
sys.path.insert(0, {tests!r})
from pathlib import Path
from support.realtime_lock import _RunLock
lock = _RunLock({run!r}, Path({base!r}))
with lock.hold(True, keep={keep}):
    print("held", flush=True)
    sys.stdin.readline()
    print("shared" if lock.share() else "kept", flush=True)
    sys.stdin.readline()
"""


def _sharer(run: str, base: Path, keep: bool = False) -> subprocess.Popen[str]:
    tests = str(Path(__file__).resolve().parent)
    proc = subprocess.Popen([sys.executable, "-c", SHARER.format(tests=tests, run=run, base=str(base), keep=keep)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


def _share(proc: subprocess.Popen[str]) -> str:
    assert proc.stdin is not None and proc.stdout is not None
    proc.stdin.write("\n")
    proc.stdin.flush()
    return proc.stdout.readline().strip()


def _holder(run: str, base: Path, exclusive: bool) -> subprocess.Popen[str]:
    tests = str(Path(__file__).resolve().parent)
    proc = subprocess.Popen([sys.executable, "-c", HOLDER.format(tests=tests, run=run, base=str(base),
                                                                  exclusive=exclusive)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


def _try(fd: int, op: int) -> bool:
    try:
        fcntl.flock(fd, op | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    fcntl.flock(fd, fcntl.LOCK_UN)
    return True


def test_a_realtime_holder_keeps_everyone_out_and_shared_holders_coexist(tmp_path: Path) -> None:
    run = f"test-{uuid.uuid4().hex}"
    mine = _RunLock(run, tmp_path)
    try:
        realtime = _holder(run, tmp_path, exclusive=True)
        try:
            assert not _try(mine._main.fileno(), fcntl.LOCK_SH)  # no ordinary test beside it
        finally:
            realtime.communicate("\n", timeout=30)
        assert _try(mine._main.fileno(), fcntl.LOCK_SH)  # released when it ended

        ordinary = _holder(run, tmp_path, exclusive=False)
        try:
            assert _try(mine._main.fileno(), fcntl.LOCK_SH)  # ordinary tests run side by side
            assert not _try(mine._main.fileno(), fcntl.LOCK_EX)  # a realtime test waits for them
        finally:
            ordinary.communicate("\n", timeout=30)
        assert _try(mine._main.fileno(), fcntl.LOCK_EX)

        # a realtime test waiting behind an ordinary one holds the turnstile: no new ordinary test starts
        ordinary = _holder(run, tmp_path, exclusive=False)
        waiting = subprocess.Popen([sys.executable, "-c", HOLDER.format(
            tests=str(Path(__file__).resolve().parent), run=run, base=str(tmp_path), exclusive=True)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        try:
            turnstile_taken = False
            for _ in range(2_000):  # until the waiter is inside the turnstile (it blocks there on main)
                if not _try(mine._turn.fileno(), fcntl.LOCK_EX):
                    turnstile_taken = True
                    break
                waiting.poll()
                assert waiting.returncode is None
                subprocess.run([sys.executable, "-c", ""], check=True)  # let the waiter run; no sleep
            # an ordinary test passes the turnstile before it takes the main lock, so none starts now
            assert turnstile_taken, "the waiting realtime holder never took the turnstile"
        finally:
            ordinary.communicate("\n", timeout=30)
            assert waiting.stdout is not None and waiting.stdout.readline().strip() == "held"
            waiting.communicate("\n", timeout=30)
    finally:
        mine.close()


def test_the_lock_files_live_in_the_runs_base_temp_folder() -> None:
    """xdist gives each worker ``<run's basetemp>/<worker id>``: the run's folder is its parent, which
    pytest's retention of old runs removes (the files are never left in the system temp dir)."""
    config = SimpleNamespace(option=SimpleNamespace(basetemp="/tmp/pytest-of-ci/pytest-7/popen-gw1"))
    assert _run_dir(config) == Path("/tmp/pytest-of-ci/pytest-7")  # type: ignore[arg-type]


def test_this_runs_lock_files_are_in_its_base_temp_folder(request: pytest.FixtureRequest) -> None:
    """The lock the plugin really took in this run: under xdist, in the parent of this worker's
    ``--basetemp`` (xdist's own layout); in one process, none at all."""
    from support import realtime_lock

    if getattr(request.config, "workerinput", None) is None:
        assert realtime_lock._lock is None
        return
    lock = realtime_lock._lock
    assert lock is not None
    main = Path(lock._main.name)
    assert main.is_file() and main.parent == Path(request.config.option.basetemp).parent


def test_a_realtime_test_done_with_the_wall_clock_lets_ordinary_tests_run_beside_it(tmp_path: Path) -> None:
    run = f"test-{uuid.uuid4().hex}"
    mine = _RunLock(run, tmp_path)
    try:
        sharer = _sharer(run, tmp_path)
        try:
            assert not _try(mine._main.fileno(), fcntl.LOCK_SH)  # its realtime part: alone
            assert _share(sharer) == "shared"
            assert _try(mine._main.fileno(), fcntl.LOCK_SH)  # an ordinary test may start beside the rest
            assert not _try(mine._main.fileno(), fcntl.LOCK_EX)  # a realtime one still waits for its end
        finally:
            sharer.communicate("\n", timeout=30)
        assert _try(mine._main.fileno(), fcntl.LOCK_EX)

        # its next test is realtime too (the lock is kept between them): it keeps the lock
        sharer = _sharer(run, tmp_path, keep=True)
        try:
            assert _share(sharer) == "kept"
            assert not _try(mine._main.fileno(), fcntl.LOCK_SH)
        finally:
            sharer.communicate("\n", timeout=30)
    finally:
        mine.close()


def test_a_realtime_test_waiting_for_the_lock_keeps_it_exclusive(tmp_path: Path) -> None:
    """flock converts by dropping the lock first: a realtime test already waiting would start beside the
    rest of the sharing one, so the lock is then kept to that test's end."""
    run = f"test-{uuid.uuid4().hex}"
    mine = _RunLock(run, tmp_path)
    sharer = _sharer(run, tmp_path)
    waiting = subprocess.Popen([sys.executable, "-c", HOLDER.format(
        tests=str(Path(__file__).resolve().parent), run=run, base=str(tmp_path), exclusive=True)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        for _ in range(2_000):  # until the waiter is inside the turnstile (it blocks there on main)
            if not _try(mine._turn.fileno(), fcntl.LOCK_EX):
                break
            waiting.poll()
            assert waiting.returncode is None
            subprocess.run([sys.executable, "-c", ""], check=True)  # let the waiter run; no sleep
        else:
            raise AssertionError("the waiting realtime holder never took the turnstile")
        assert _share(sharer) == "kept"
        assert not _try(mine._main.fileno(), fcntl.LOCK_SH)
    finally:
        sharer.communicate("\n", timeout=30)
        assert waiting.stdout is not None and waiting.stdout.readline().strip() == "held"  # then the waiter
        waiting.communicate("\n", timeout=30)
        mine.close()


def test_realtime_part_done_in_an_ordinary_test_changes_nothing() -> None:
    """Without xdist there is no lock; under xdist this ordinary test holds it shared already."""
    from support import realtime_lock

    assert realtime_lock.realtime_part_done() is False


#: a worker in background mode: holds the lock around one test and reports its own nice value
BACKGROUND = """
import os, sys
sys.path.insert(0, {tests!r})
from pathlib import Path
from support.realtime_lock import BACKGROUND_NICE, _RunLock, set_tree_nice
set_tree_nice(os.getpid(), BACKGROUND_NICE)  # as pytest_configure leaves a worker
lock = _RunLock({run!r}, Path({base!r}), background=True, base_nice={base_nice})
with lock.hold({exclusive}):
    print("held", os.getpriority(os.PRIO_PROCESS, 0), flush=True)
    sys.stdin.readline()
    if {call_share}:  # realtime_part_done()
        print("shared" if lock.share() else "kept", os.getpriority(os.PRIO_PROCESS, 0), flush=True)
    else:
        print("running", os.getpriority(os.PRIO_PROCESS, 0), flush=True)
    sys.stdin.readline()
print("done", os.getpriority(os.PRIO_PROCESS, 0), flush=True)
sys.stdin.readline()
"""

#: the first nice value of the holders' workers (not 19, whatever this test process runs at)
BASE = 5
#: the holders come back to BASE from 19 (this process may run at 19 itself: a worker in background mode)
needs_background = pytest.mark.skipif(not sys.platform.startswith("linux") or not _may_lower_nice_to(BASE),
                                      reason="needs Linux and root or CAP_SYS_NICE to lower a nice value")
IDLE = BACKGROUND_NICE


def _background(run: str, base: Path, exclusive: bool, call_share: bool = True) -> subprocess.Popen[str]:
    tests = str(Path(__file__).resolve().parent)
    return subprocess.Popen([sys.executable, "-c", BACKGROUND.format(tests=tests, run=run, base=str(base),
                                                                      exclusive=exclusive, base_nice=BASE,
                                                                      call_share=call_share)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)


def _said(proc: subprocess.Popen[str]) -> tuple[str, int]:
    assert proc.stdout is not None
    word, nice = proc.stdout.readline().split()
    return word, int(nice)


def _step(proc: subprocess.Popen[str]) -> tuple[str, int]:
    assert proc.stdin is not None
    proc.stdin.write("\n")
    proc.stdin.flush()
    return _said(proc)


def test_alone_is_kept_when_asked_for() -> None:
    for value in ("1", " 1 ", "yes", "true"):
        assert background_possible({"GHOSTSHELL_TESTS_REALTIME_ALONE": value}) is False, value
    if sys.platform.startswith("linux") and _may_lower_nice_to(os.getpriority(os.PRIO_PROCESS, 0)) \
            and os.getpriority(os.PRIO_PROCESS, 0) < BACKGROUND_NICE:
        for value in ("", "0", " 0 "):
            assert background_possible({"GHOSTSHELL_TESTS_REALTIME_ALONE": value}) is True, value


def test_a_run_started_at_nice_19_keeps_realtime_tests_alone_and_asking_changes_nothing() -> None:
    """At 19 a realtime test could not rank above the rest; the question leaves the nice value alone."""
    code = ("import os, sys; sys.path.insert(0, {tests!r}); from support.realtime_lock import background_possible; "
            "before = os.getpriority(os.PRIO_PROCESS, 0); ok = background_possible({{}}); "
            "print(before, ok, os.getpriority(os.PRIO_PROCESS, 0))").format(tests=str(Path(__file__).resolve().parent))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                         preexec_fn=lambda: os.setpriority(os.PRIO_PROCESS, 0, 19))
    assert out.stdout.split() == ["19", "False", "19"], out.stdout + out.stderr


@needs_background
def test_a_process_tree_changes_nice_value_together() -> None:
    """The worker, its child and the child's own thread (a host that started a board) all move."""
    parent = subprocess.Popen(
        [sys.executable, "-c", "import subprocess, sys, threading; c = subprocess.Popen([sys.executable, '-c', "
                               "'import sys; print(1, flush=True); sys.stdin.readline()'], stdin=subprocess.PIPE, "
                               "stdout=subprocess.PIPE, text=True); t = threading.Thread(target=sys.stdin.readline); "
                               "t.start(); print(c.pid, t.native_id, c.stdout.readline().strip(), flush=True); "
                               "t.join(); c.communicate('x')"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    before = os.getpriority(os.PRIO_PROCESS, 0)
    try:
        assert parent.stdout is not None
        child_pid, thread_id, ready = parent.stdout.readline().split()
        assert ready == "1"
        ids = [parent.pid, int(child_pid), int(thread_id)]
        set_tree_nice(parent.pid, BASE)  # from wherever they started (a worker in background mode: 19)
        assert [os.getpriority(os.PRIO_PROCESS, i) for i in ids] == [BASE] * 3
        set_tree_nice(parent.pid, IDLE)
        assert [os.getpriority(os.PRIO_PROCESS, i) for i in ids] == [IDLE] * 3
        assert os.getpriority(os.PRIO_PROCESS, 0) == before  # the caller is not below the root
        set_tree_nice(parent.pid, BASE)
        assert [os.getpriority(os.PRIO_PROCESS, i) for i in ids] == [BASE] * 3
    finally:
        parent.communicate("\n", timeout=30)


@needs_background
def test_background_mode_lets_ordinary_tests_run_beside_a_realtime_one_at_nice_19(tmp_path: Path) -> None:
    run = f"test-{uuid.uuid4().hex}"
    mine = _RunLock(run, tmp_path, background=True)
    realtime = _background(run, tmp_path, exclusive=True)
    ordinary = _background(run, tmp_path, exclusive=False)
    try:
        assert _said(realtime) == ("held", BASE)  # its tree back at the worker's first nice value
        assert _said(ordinary) == ("held", IDLE)  # started beside it, at nice 19
        assert not _try(mine._main.fileno(), fcntl.LOCK_EX)  # another realtime test waits
        assert _step(ordinary) == ("kept", IDLE)  # realtime_part_done in an ordinary test: nothing
        # realtime_part_done: the rest of the test at nice 19, and the next realtime test may start
        assert _step(realtime) == ("shared", IDLE)
        assert _try(mine._main.fileno(), fcntl.LOCK_EX)
        assert _step(realtime) == ("done", IDLE)
    finally:
        for proc in (realtime, ordinary):
            proc.communicate("\n\n\n", timeout=30)
        mine.close()


@needs_background
def test_background_mode_returns_a_realtime_worker_to_nice_19_when_the_test_ends(tmp_path: Path) -> None:
    run = f"test-{uuid.uuid4().hex}"
    mine = _RunLock(run, tmp_path, background=True)
    first = _background(run, tmp_path, exclusive=True, call_share=False)  # never calls realtime_part_done
    assert _said(first) == ("held", BASE)
    second = _background(run, tmp_path, exclusive=True)  # waits for the first to let go
    try:
        assert _step(first) == ("running", BASE)  # still its test: still at the base value
        assert _step(first) == ("done", IDLE)  # its test ended: back at 19, and the lock let go
        assert _said(second) == ("held", BASE)
        assert _step(second) == ("shared", IDLE)
        assert _step(second) == ("done", IDLE)
    finally:
        for proc in (first, second):
            proc.communicate("\n\n\n", timeout=30)
        mine.close()


@needs_background
def test_a_waiting_thread_polls_at_the_base_value_and_its_subprocesses_stay_at_19(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import threading

    from support import realtime_lock

    lock = _RunLock(uuid.uuid4().hex, tmp_path, background=True, base_nice=BASE)
    monkeypatch.setattr(realtime_lock, "_lock", lock)
    seen: dict[str, int] = {}

    def in_an_ordinary_test() -> None:  # a thread of its own: the value moves back and forth on it alone
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, 19)
        child = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
        try:
            with realtime_lock.attentive():
                seen["polling"] = os.getpriority(os.PRIO_PROCESS, tid)
                seen["child"] = os.getpriority(os.PRIO_PROCESS, child.pid)  # started at 19, from this thread
            seen["after"] = os.getpriority(os.PRIO_PROCESS, tid)
        finally:
            child.communicate(b"")

    t = threading.Thread(target=in_an_ordinary_test)
    t.start()
    t.join()
    assert seen == {"polling": BASE, "child": 19, "after": 19}
    lock.close()
