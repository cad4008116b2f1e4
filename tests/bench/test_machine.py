"""bench/_machine.py: the machine floor the latency benchmark prints (steal from /proc/stat, wake-up lateness)."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import numpy as np
import pytest

_SPEC = importlib.util.spec_from_file_location("bench_machine", Path(__file__).resolve().parents[2] / "bench" / "_machine.py")
assert _SPEC is not None and _SPEC.loader is not None
machine = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(machine)


def test_steal_is_the_eighth_column_in_user_hz_ticks(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    stat = tmp_path / "stat"
    stat.write_text("cpu  1102019 4307 173057 1469907 13698 0 1426 750 0 0\ncpu0 1 2 3 4 5 6 7 8 9 10\n")
    monkeypatch.setattr(machine.os, "sysconf", lambda name: 250 if name == "SC_CLK_TCK" else os.sysconf(name))
    assert machine.cpu_steal_s(str(stat)) == pytest.approx(3.0)


@pytest.mark.parametrize("text", ["", "cpu 1 2 3\n", "intr 1 2 3 4 5 6 7 8 9\n"])
def test_no_steal_column_is_none_not_an_error(tmp_path: Path, text: str) -> None:
    stat = tmp_path / "stat"
    stat.write_text(text)
    assert machine.cpu_steal_s(str(stat)) is None
    assert machine.cpu_steal_s(str(tmp_path / "missing")) is None


class _FakeClock:
    """perf_counter and sleep of a machine whose every sleep returns 1 ms late."""

    def __init__(self) -> None:
        self.t = 100.0

    def perf_counter(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.t += s + 0.001


def test_wakeup_lateness_is_in_milliseconds_one_per_sleep(monkeypatch: pytest.MonkeyPatch) -> None:
    clock = _FakeClock()
    monkeypatch.setattr(machine.time, "perf_counter", clock.perf_counter)
    monkeypatch.setattr(machine.time, "sleep", clock.sleep)
    late = machine.wakeup_lateness_ms(5, 0.002)
    assert late.shape == (5,) and late == pytest.approx([1.0] * 5, abs=1e-6)
    assert clock.t == pytest.approx(100.0 + 5 * 0.003)


def test_floor_and_steal_lines() -> None:
    s = machine.floor_stats(np.array([0.05, 0.07, 0.07, 2.5]))
    assert s["n"] == 4 and s["p50"] == 0.07 and s["max"] == 2.5
    assert machine.floor_line("start", s) == (
        f"machine floor (start): a 2 ms sleep wakes late by p50 0.070, p99 {s['p99']:.3f}, max 2.500 ms (n=4)")
    line = machine.steal_line(3.0, 100.0, 2)
    assert "3.00 CPU-s over 100 s on 2 CPUs (1.5 % of their time" in line
    assert "(0.0 %" in machine.steal_line(0.0, 0.0, 2)  # a run of no time divides by nothing


@pytest.mark.parametrize("n,period", [(0, 0.002), (3, 0.0), (3, -1.0)])
def test_wakeup_lateness_refuses_nonsense(n: int, period: float) -> None:
    with pytest.raises(ValueError):
        machine.wakeup_lateness_ms(n, period)
