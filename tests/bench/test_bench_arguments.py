"""The task benchmarks refuse a bad ``--tasks``, ``--robot`` or ``--baud`` as argparse refuses a bad option
(its usage and one ``error:`` line, exit status 2), before any run starts (a new user's ``--tasks 3-1`` and
``--tasks ''`` used to run all 30 tasks; ``--baud -1`` and ``--robot nosuch`` ended in a traceback and
``--tasks 99`` in status 1)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench"


@pytest.mark.parametrize(("args", "says"), [
    (["--tasks", "3-1"], "runs backwards"),
    (["--tasks", ""], "no task ids"),
    (["--tasks", " , "], "no task ids"),
    (["--tasks", "1,x"], "expected ids like"),
    (["--tasks", "0"], "no ground truth for task(s) [0]"),
    (["--tasks", "99"], "no ground truth for task(s) [99]"),
    (["--tasks", "1", "--baud", "-1"], "--baud: must be 1..12000000 bit/s"),
    (["--tasks", "1", "--baud", "0"], "--baud: must be 1..12000000 bit/s"),
    (["--tasks", "1", "--baud", "99999999999"], "--baud: must be 1..12000000 bit/s"),
    (["--robot", "nosuch"], "--robot: no robot 'nosuch'"),
    (["--tasks", "1-100000000000"], "names more than 1000 tasks"),  # was a MemoryError
    (["--tasks", "3", "--tokens-per-s", "-3"], "--tokens-per-s: expected a finite number > 0"),
    (["--tasks", "3", "--tokens-per-s", "nan"], "--tokens-per-s: expected a finite number > 0"),
    (["--tasks", "3", "--json", "/nonexistent/dir/x.json"], "--json: no folder"),  # was an error after the run
    (["--tasks", "3", "--link", ""], "--link: bad link spec ''"),
])
def test_bench_latency_refuses_bad_arguments(args: list[str], says: str, tmp_path: Path) -> None:
    out = ["--out", str(tmp_path)] if "--out" not in args else []
    r = subprocess.run([sys.executable, str(BENCH / "bench_latency.py"), "--floor", "0", *out, *args],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert says in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith("bench_latency.py: error: "), r.stderr
    assert "token -> servo latency" not in r.stdout  # refused before any run started


@pytest.mark.parametrize(("args", "says"), [
    (["--tasks", "3-1"], "runs backwards"),
    (["--robot", "nosuch"], "--robot: no robot 'nosuch'"),
    (["--tasks", "3", "--tokens-per-s", "0"], "--tokens-per-s: expected a finite number > 0"),
])
def test_bench_streaming_refuses_bad_arguments(args: list[str], says: str, tmp_path: Path) -> None:
    r = subprocess.run([sys.executable, str(BENCH / "bench_streaming.py"), "--out", str(tmp_path), *args],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert says in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert "time to first action" not in r.stdout  # refused before any run started


def test_an_out_folder_that_cannot_be_made_is_refused_before_any_run(tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    r = subprocess.run([sys.executable, str(BENCH / "bench_latency.py"), "--floor", "0", "--tasks", "3",
                        "--out", str(blocker / "runs")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "--out: cannot make the folder" in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_a_link_no_board_can_serve_is_one_line_and_status_2(tmp_path: Path) -> None:
    """``--link nosuch`` is a well-formed spec (a serial device path) that no board can open: one line
    once the first run tries it, not a LinkConfigError traceback."""
    r = subprocess.run([sys.executable, str(BENCH / "bench_latency.py"), "--floor", "0", "--tasks", "3",
                        "--link", str(tmp_path / "nosuch"), "--out", str(tmp_path / "runs")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert "bench_latency: the emulated board cannot serve" in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_a_task_named_twice_runs_once() -> None:
    """``--tasks 1,1`` ran task 1 twice (the second run overwrote the first's folder and counted twice)."""
    sys.path.insert(0, str(BENCH))
    try:
        from _tasks_common import task_ids
    finally:
        sys.path.remove(str(BENCH))
    assert task_ids("1,1") == [1]
    assert task_ids("3-5,4,1,3") == [3, 4, 5, 1]
