"""bench/_machine.py: the machine floor the latency benchmark prints (steal from /proc/stat, wake-up lateness)."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pytest

_SPEC = importlib.util.spec_from_file_location("bench_machine", Path(__file__).resolve().parents[2] / "bench" / "_machine.py")
assert _SPEC is not None and _SPEC.loader is not None
machine = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(machine)


def test_steal_is_the_eighth_column_in_seconds(tmp_path: Path) -> None:
    stat = tmp_path / "stat"
    hz = os.sysconf("SC_CLK_TCK")
    stat.write_text(f"cpu  1102019 4307 173057 1469907 13698 0 1426 {3 * hz} 0 0\ncpu0 1 2 3 4 5 6 7 8 9 10\n")
    assert machine.cpu_steal_s(str(stat)) == pytest.approx(3.0)


@pytest.mark.parametrize("text", ["", "cpu 1 2 3\n", "intr 1 2 3 4 5 6 7 8 9\n"])
def test_no_steal_column_is_none_not_an_error(tmp_path: Path, text: str) -> None:
    stat = tmp_path / "stat"
    stat.write_text(text)
    assert machine.cpu_steal_s(str(stat)) is None
    assert machine.cpu_steal_s(str(tmp_path / "missing")) is None


def test_wakeup_lateness_has_one_value_per_sleep() -> None:
    late = machine.wakeup_lateness_ms(5, 0.0005)
    assert late.shape == (5,) and (late > -0.05).all()  # a sleep never returns (much) early


@pytest.mark.parametrize("n,period", [(0, 0.002), (3, 0.0), (3, -1.0)])
def test_wakeup_lateness_refuses_nonsense(n: int, period: float) -> None:
    with pytest.raises(ValueError):
        machine.wakeup_lateness_ms(n, period)
