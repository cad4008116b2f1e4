"""Paper tasks end to end on the C firmware whose servos speak Dynamixel Protocol 2.0 (the launcher's in-process
plant in ``dxl2`` mode, ``LaunchOptions(bus_protocol="dxl2")``), native and on QEMU, checked as every board's
runs are (tests/e2e/task_checks.py), and task 26's call timeline the same as on the STS bus.

The board is the launcher itself (:func:`firmware_sim.cfirmware.launcher.run_firmware` in a subprocess, its
frame log where the checks read it); the run connects to its pty (``emulate_board=False``). Lockstep, so the
runs are reproducible whatever the machine's load.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from e2e.conftest import TASKS, E2ERun, run_e2e
from e2e.task_checks import check_common, check_task

from .test_c_servo_bus import _readline

ROOT = Path(__file__).resolve().parents[2]
TICK_S = 0.002
_BOARD = """
import sys
from firmware_sim.cfirmware.launcher import LaunchOptions, run_firmware
from robots.registry import load_robot
sys.exit(run_firmware(LaunchOptions(robot=load_robot("coco"), firmware=sys.argv[1], lockstep=True,
                                    bus_protocol=sys.argv[2], log_path=sys.argv[3])))
"""
_RUNS: dict[tuple[int, str, str], E2ERun] = {}


@contextmanager
def launched_board(firmware: str, protocol: str, out: Path) -> Iterator[str]:
    """The launcher as the board (its host pty's path); stopped by SIGTERM, as the host stops a board."""
    out.mkdir(parents=True, exist_ok=True)
    err = open(out / "board.stderr", "wb")
    proc = subprocess.Popen([sys.executable, "-c", _BOARD, firmware, protocol, str(out / "board_frames.jsonl")],
                            stdout=subprocess.PIPE, stderr=err, stdin=subprocess.DEVNULL, cwd=ROOT,
                            env=dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl")))
    try:
        assert proc.stdout is not None
        yield _readline(proc.stdout, "board: listening on ", proc, out / "board.stderr").split()[-1]
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        err.close()


def _run(tid: int, firmware: str, protocol: str, tmp: pytest.TempPathFactory) -> E2ERun:
    key = (tid, firmware, protocol)
    if key not in _RUNS:
        out = tmp.mktemp(f"task{tid}-{firmware}-{protocol}")
        with launched_board(firmware, protocol, out) as pty:
            _RUNS[key] = run_e2e(TASKS[tid].ground_truth, out, task_label=f"task {tid}", link=pty,
                                 emulate_board=False)
    return _RUNS[key]


@pytest.mark.parametrize("tid", [1, 26])
def test_task_on_the_native_firmware_over_dynamixel(tid: int, tmp_path_factory: pytest.TempPathFactory) -> None:
    run = _run(tid, "c", "dxl2", tmp_path_factory)
    check_common(run, "c")
    check_task(tid, run, "c")
    err = (run.out / "board.stderr").read_text()
    assert "board: servo bus (dxl2): 12 servos (model 1200)" in err, err[-2000:]
    assert "SERVO_FAULT" not in err and "stopped answering" not in err


def test_task26_timeline_same_over_dynamixel_and_feetech(tmp_path_factory: pytest.TempPathFactory) -> None:
    dxl, sts = _run(26, "c", "dxl2", tmp_path_factory), _run(26, "c", "sts", tmp_path_factory)
    assert [c.path for c in dxl.calls] == [c.path for c in sts.calls]
    for a, b in zip(dxl.calls, sts.calls):
        if a.persistent and a.ended_by is None:
            continue  # ended by the host at its board-time estimate (tests/cfirmware/test_qemu_tasks.py)
        assert abs((a.start - dxl.t0) - (b.start - sts.t0)) <= TICK_S + 1e-9, (a.path, a.start, b.start)
        assert abs((a.end - dxl.t0) - (b.end - sts.t0)) <= TICK_S + 1e-9, (a.path, a.end, b.end)


@pytest.mark.slow
def test_task_on_qemu_over_dynamixel(tmp_path_factory: pytest.TempPathFactory) -> None:
    run = _run(1, "qemu", "dxl2", tmp_path_factory)
    check_common(run, "qemu")
    check_task(1, run, "qemu")
    assert "board: servo bus (dxl2): 12 servos (model 1200)" in (run.out / "board.stderr").read_text()
