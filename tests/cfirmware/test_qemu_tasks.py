"""The C firmware as a Cortex-M3 image on QEMU (``--firmware qemu``: ``qemu-system-arm -M mps2-an385``,
UART0 the host's pty, UART1 the servo-bus plant): tasks 1, 23 and 26 end to end, checked as the
Python board's runs are (tests/e2e/test_tasks_e2e.py, checks in tests/e2e/task_checks.py), and task 26's call timeline is the Python
board's and the native C firmware's (board-measured starts and ends within one control tick).

Lockstep, not realtime: the board's virtual clock advances only with the host's frames and ADVANCE,
so the run is reproducible however slowly QEMU executes (its UARTs cost a main-loop round per byte);
``-icount`` would make QEMU's own clock deterministic but is not needed for that, and is used only
for the tick-cost figure (bench/bench_cfirmware.py).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from e2e.conftest import TASKS, E2ERun, run_e2e
from e2e.task_checks import check_common, check_task

TICK_S = 0.002
#: a persistent call (background music) is ended by the host when the program ends, at its board-time
#: estimate, which in lockstep is the last telemetry report it has read (50 Hz): whether the report
#: of the program's last tick arrived before the end was processed depends on scheduling, so that end
#: is compared to one report period (seen under a loaded machine: 5.33 s vs 5.35 s on QEMU)
REPORT_S = 0.02
_RUNS: dict[tuple[int, str], E2ERun] = {}


def _run(tid: int, firmware: str, tmp: pytest.TempPathFactory) -> E2ERun:
    if (tid, firmware) not in _RUNS:
        out: Path = tmp.mktemp(f"task{tid}-{firmware}")
        _RUNS[(tid, firmware)] = run_e2e(TASKS[tid].ground_truth, out, task_label=f"task {tid}", firmware=firmware)
    return _RUNS[(tid, firmware)]


@pytest.mark.slow
@pytest.mark.parametrize("tid", [1, 23, 26])
def test_task_on_qemu(tid: int, tmp_path_factory: pytest.TempPathFactory) -> None:
    run = _run(tid, "qemu", tmp_path_factory)
    check_common(run, "qemu")
    check_task(tid, run, "qemu")
    err = (run.out / "board.stderr").read_text()
    assert "C firmware" in err and "servo bus" in err


@pytest.mark.slow
def test_task26_timeline_same_on_every_board(tmp_path_factory: pytest.TempPathFactory) -> None:
    runs = {fw: _run(26, fw, tmp_path_factory) for fw in ("python", "c", "qemu")}
    for fw, run in runs.items():
        assert_same_timeline(fw, run, runs["python"])


def assert_same_timeline(fw: str, run: E2ERun, ref: E2ERun) -> None:
    """``run``'s calls (on firmware ``fw``) are ``ref``'s, each starting and ending within one control tick of
    it (board time since each run's start), but for what a persistent call's end releases (below)."""
    # a call released by a persistent call's end (the next <wait> block after one) starts when that end
    # is seen, so within the same report period (a CI run: play_bgm[0]/wait[2] at 3.82 s vs 3.80 s on QEMU)
    # ... and every call that starts after it is later by the same amount (a CI run: its move_strides
    # 3.87 s vs 3.85 s, its end 5.29 vs 5.27): those are compared within one tick of that shift
    ends = [b.end for b in ref.calls if b.persistent and b.ended_by is None and b.end is not None]
    assert [c.path for c in run.calls] == [c.path for c in ref.calls], fw
    shift, since = 0.0, float("inf")  # the run's lag behind the reference from board time `since` on
    for a, b in sorted(zip(run.calls, ref.calls), key=lambda pair: pair[1].start):
        lag = (a.start - run.t0) - (b.start - ref.t0)
        if any(abs(b.start - e) < 1e-9 for e in ends):  # released by a persistent call's end
            assert abs(lag) <= REPORT_S + 1e-9, (fw, a.path, a.start, b.start)
            shift, since = lag, b.start
        base = shift if b.start >= since else 0.0
        assert abs(lag - base) <= TICK_S + 1e-9, (fw, a.path, a.start, b.start, base)
        tol = REPORT_S if a.persistent and a.ended_by is None else TICK_S
        end_lag = (a.end - run.t0) - (b.end - ref.t0)
        assert abs(end_lag - base) <= tol + 1e-9, (fw, a.path, a.end, b.end, base)
