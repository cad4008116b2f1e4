"""The C firmware's STM32F405 image on QEMU (``--firmware stm32f4``: ``qemu-system-arm -M netduinoplus2``,
USART2 the host's pty, USART6 the servo-bus plant, USART3 the log): tasks 1, 23 and 26 end to end in lockstep
and in realtime, checked as the Python board's runs are (tests/e2e/task_checks.py), task 26's call timeline
the Python board's (tests/cfirmware/test_qemu_tasks.py ``assert_same_timeline``: within one control tick);
a boot block with a bad check word is ignored (the defaults apply); garbage on the host UART before the
handshake does not stop it answering.

Runs are cached per module (tid, firmware, mode), and the lockstep ones share test_qemu_tasks.py's cache (its
Python board's task 26 is the reference for both).
"""

from __future__ import annotations

import os
import random
import select
import subprocess
import time
from pathlib import Path

import pytest

from cfirmware.test_qemu_tasks import _run, assert_same_timeline
from cfirmware.wire import Wire
from e2e.conftest import TASKS, E2ERun, run_e2e
from e2e.task_checks import check_common, check_task
from firmware_sim.cfirmware.build import build
from firmware_sim.cfirmware.launcher import LaunchOptions, firmware_command
from host.run.realtime_health import board_lateness
from protocol.codec import SCHEMA_HASH
from protocol.messages import PROTOCOL_VERSION, Caps, Hello
from robots.registry import DEFAULT_ROBOT, load_robot

FW = "stm32f4"
_REALTIME: dict[int, E2ERun] = {}


def _realtime(tid: int, tmp: pytest.TempPathFactory) -> E2ERun:
    if tid not in _REALTIME:
        out: Path = tmp.mktemp(f"task{tid}-{FW}-realtime")
        _REALTIME[tid] = run_e2e(TASKS[tid].ground_truth, out, task_label=f"task {tid}", firmware=FW, lockstep=False)
    return _REALTIME[tid]


@pytest.mark.slow
# realtime: on the wall clock, one at a time under xdist (tests/support/realtime_lock.py)
@pytest.mark.parametrize("mode", ["lockstep", pytest.param("realtime", marks=pytest.mark.realtime)])
@pytest.mark.parametrize("tid", [1, 23, 26])
def test_task_on_stm32f4(tid: int, mode: str, tmp_path_factory: pytest.TempPathFactory) -> None:
    run = _run(tid, FW, tmp_path_factory) if mode == "lockstep" else _realtime(tid, tmp_path_factory)
    behind = mode == "realtime" and fell_behind(run)
    check_common(run, FW, late_ok=behind)
    # task 23's own check (exactly one FLUSH of the head servos, after the last stride) holds in lockstep only: in
    # realtime the host also flushes the head ~0.5 s into the run on every board (the Python board, the native C
    # firmware and this image alike, measured 2026-12-07), so only the common checks apply to that run. A realtime
    # run that fell behind the wall clock (and said so) keeps its calls and their order, not the tasks' timings
    # (a CI run at load 6 on 2 cores: the host skipped 64 frames, head_act started 0.40 s after shake_ear ended)
    if (tid, mode) != (23, "realtime") and not behind:
        check_task(tid, run, FW)
    err = (run.out / "board.stderr").read_text()
    assert "C firmware" in err and "servo bus" in err
    assert "board: clock: " in err  # the port's clock line (QEMU: no RCC, the HSI fallback said so)


@pytest.mark.slow
def test_task26_timeline_same_as_the_python_board(tmp_path_factory: pytest.TempPathFactory) -> None:
    assert_same_timeline(FW, _run(26, FW, tmp_path_factory), _run(26, "python", tmp_path_factory))


def fell_behind(run: E2ERun) -> bool:
    """Whether a realtime run says it fell behind the wall clock: the board's ``board: realtime lateness`` record
    (ticks overrun or skipped, servo reads unanswered, the plant behind) or the host (frames it skipped, being
    late itself; summary.json ``extra["realtime_behind"]``). Only then may frames have been late: QEMU and the host
    on a loaded two-core machine are descheduled now and then, which a run reports as lateness (never as a fault);
    a late frame in a run that kept up is a failure."""
    rec = board_lateness(run.out / "board.stderr")
    assert rec is not None, "a realtime C firmware run ends with its lateness record"
    extra = run.report.summary.extra
    return (any(rec.get(k, 0) > 0 for k in ("board_overruns", "board_ticks_skipped", "bus_stalls",
                                            "bus_late_replies", "plant_late_steps", "plant_behind_max_ms"))
            or (extra["link"].get("frames_skipped") or 0) > 0 or extra.get("realtime_behind") is not None)


def _boot_lines(cmd: list[str], until: str, timeout: float = 60.0) -> str:
    """Start QEMU (``cmd``), read its log channel (stdout) until a whole line starting with ``until``; returns the
    text."""
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    assert proc.stdout is not None
    out = b""
    end = time.monotonic() + timeout
    try:
        while time.monotonic() < end and b"\n" not in out.partition(until.encode())[2]:  # that line, whole
            ready, _, _ = select.select([proc.stdout], [], [], 1.0)
            if ready:
                data = os.read(proc.stdout.fileno(), 65536)
                if not data:
                    break
                out += data
    finally:
        proc.kill()
        proc.wait()
    text = out.decode("utf-8", "replace")
    assert until in text, f"no {until!r} line within {timeout} s: {text[-1500:]!r}"
    return text


def test_a_bad_check_word_leaves_the_defaults() -> None:
    robot = load_robot(DEFAULT_ROBOT)
    exe = build(FW, robot)
    cmd = firmware_command(LaunchOptions(robot=robot, firmware=FW, lockstep=True, rate_hz=250), exe, "null", "null")
    good = _boot_lines(cmd, "board: boot settings")
    assert "board: boot settings: the configuration block's" in good
    assert "board: clock: HSE 8 MHz: not ready" in good and "running on the 16 MHz HSI" in good
    last = max(i for i, a in enumerate(cmd) if a.startswith("loader,addr="))
    parts = [f"data={int(p[5:], 16) ^ 1:#x}" if p.startswith("data=") else p for p in cmd[last].split(",")]
    cmd[last] = ",".join(parts)  # the check word no longer matches
    bad = _boot_lines(cmd, "board: boot settings")
    assert "board: boot settings: the defaults (no valid configuration block)" in bad


@pytest.mark.slow
def test_garbage_on_the_host_uart_then_a_handshake(tmp_path: Path) -> None:
    rng = random.Random(7)
    w = Wire(["--lockstep", "--firmware", FW], tmp_path / "board.stderr")
    try:
        for _ in range(8):  # runs of random bytes, delimiters among them (broken frames of every length)
            w.raw(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300))) + b"\x00")
        w.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0))
        w.wait(lambda: w.of(Caps), timeout=120, what="CAPS after the garbage")
    finally:
        assert w.close() in (0, 130)
