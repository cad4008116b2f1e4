"""Every benchmark still runs (tiny sizes); their numbers are printed, never asserted."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench"

CASES = {
    "bench_codec.py": ["--seconds", "0.05"],
    "bench_call_path.py": ["--runs", "1"],  # one lockstep turn under a profiler
    "bench_parser.py": ["--mb", "0.05"],
    "bench_board.py": ["--lockstep-only", "--rounds", "1", "--sim-seconds", "2"],  # realtime parts: REALTIME_PARTS
    "bench_roundtrip.py": ["--n", "20"],
    "bench_streaming.py": ["--tasks", "5"],
    "bench_latency.py": ["--tasks", "5", "--lockstep"],
    "bench_canload.py": ["--no-run"],
    "bench_hostile.py": ["--mb", "0.01", "--calls", "50"],
    "bench_recovery.py": ["--links", "pty", "--starts", "3"],  # one realtime run, ~9 s
    "bench_can.py": ["--n", "20", "--seconds", "0.3", "--skip", "session,latency"],  # one short UML boot
    # QEMU boot + native builds; the STM32F405 tick figure from task 1 (one call) rather than 26
    "bench_cfirmware.py": ["--seconds", "0.3", "--repeat", "1", "--skip-fuzz", "--f4-task", "1"],
    "bench_foxglove.py": ["--n", "1", "--task", "1"],  # one realtime run with a live client, two lockstep runs
    "bench_recording.py": ["--seconds", "0.3"],  # CoCo's RunLog on a loop: none, inline, writer thread
    "bench_fuzz.py": ["--seconds", "1", "serial-decoder"],  # one libFuzzer run of 1 s
    "run_all.py": ["--quick", "--only", "board"],  # the table, from the board's figures
    "bench_soak.py": ["-n", "1", "--seed", "1", "--links", "pty", "--realtime-share", "0"],  # one lockstep run
    "bench_control_lag.py": ["-n", "1", "--cases", "mesh"],  # one realtime run of the mesh arm
    "bench_lockstep_identity.py": ["--runs", "1", "--robot", "arm", "--p", "0", "--max-s", "0"],  # ~3 s
    "bench_realtime_load.py": ["--runs", "1", "--firmware", "python", "--no-load", "--task", "1"],  # ~5 s
    "bench_servo_bus.py": ["--cycles", "5", "--robots", "arm"],  # two plants on ptys, the vendor SDKs as clients
    "bench_eval.py": ["--rounds", "1", "--tasks", "1,2", "--no-plots"],  # eval with 1 and 2 workers, 2 tasks each
}


#: cases that run a board on the wall clock (under xdist, one at a time and first in line for the cores: tests/support/realtime_lock.py)
REALTIME = {"bench_roundtrip.py", "bench_foxglove.py", "bench_recovery.py", "bench_control_lag.py",
            "bench_realtime_load.py"}

#: a benchmark's wall-clock parts run as a case of their own, so its lockstep parts (most of its time)
#: do not hold the other workers off (tests/support/realtime_lock.py)
REALTIME_PARTS = {"bench_board.py": ["--realtime-only", "--seconds", "0.5"]}


def _env(tmp_path: Path) -> dict[str, str]:
    """The benchmark's environment: its default artefact folders (``tempfile.mkdtemp``, kept for the
    user to read) go under the test's own temporary folder, not into the system's."""
    return dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"), TMPDIR=str(tmp_path))


def _bench(script: str, args: list[str], tmp_path: Path) -> subprocess.CompletedProcess[str]:
    """Run ``bench/script args`` in ``tmp_path``; it must exit 0 and print something."""
    r = subprocess.run([sys.executable, str(BENCH / script), *args], cwd=tmp_path, env=_env(tmp_path),
                       capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, f"{script} failed:\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}"
    assert r.stdout.strip(), f"{script} printed nothing"
    return r


@pytest.mark.parametrize("script", [pytest.param(s, marks=pytest.mark.realtime) if s in REALTIME else s
                                    for s in sorted(CASES)])
def test_benchmark_runs(script: str, tmp_path: Path) -> None:
    _bench(script, CASES[script], tmp_path)


@pytest.mark.realtime
@pytest.mark.parametrize("script", sorted(REALTIME_PARTS))
def test_benchmark_realtime_parts_run(script: str, tmp_path: Path) -> None:
    _bench(script, REALTIME_PARTS[script], tmp_path)


def test_every_benchmark_has_a_smoke_case() -> None:
    scripts = {p.name for p in BENCH.glob("*.py") if not p.name.startswith("_")}
    assert scripts == set(CASES)


#: the benchmarks that take ``--link``, over SLCAN (the board is a USB-CAN adapter on a pty)
SLCAN_CASES = {
    "bench_roundtrip.py": ["--n", "20", "--link", "can:slcan:pty"],
    "bench_latency.py": ["--tasks", "5", "--lockstep", "--link", "can:slcan:pty"],
}


@pytest.mark.realtime
@pytest.mark.parametrize("script", sorted(SLCAN_CASES))
def test_benchmark_runs_over_slcan(script: str, tmp_path: Path) -> None:
    r = _bench(script, SLCAN_CASES[script], tmp_path)
    assert "can:slcan:pty" in r.stdout and "p50=" in r.stdout, r.stdout[-2000:]
