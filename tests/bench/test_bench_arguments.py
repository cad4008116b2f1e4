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
    (["--tasks", "1", "--baud", "-1"], "--baud: expected a baud rate >= 1"),
    (["--tasks", "1", "--baud", "0"], "--baud: expected a baud rate >= 1"),
    (["--robot", "nosuch"], "--robot: no robot 'nosuch'"),
])
def test_bench_latency_refuses_bad_arguments(args: list[str], says: str, tmp_path: Path) -> None:
    r = subprocess.run([sys.executable, str(BENCH / "bench_latency.py"), "--floor", "0", "--out", str(tmp_path), *args],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert says in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith("bench_latency.py: error: "), r.stderr
    assert "token -> servo latency" not in r.stdout  # refused before any run started


@pytest.mark.parametrize(("args", "says"), [
    (["--tasks", "3-1"], "runs backwards"),
    (["--robot", "nosuch"], "--robot: no robot 'nosuch'"),
])
def test_bench_streaming_refuses_bad_arguments(args: list[str], says: str, tmp_path: Path) -> None:
    r = subprocess.run([sys.executable, str(BENCH / "bench_streaming.py"), "--out", str(tmp_path), *args],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert says in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert "time to first action" not in r.stdout  # refused before any run started
