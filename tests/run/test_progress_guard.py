"""The no-progress guard (host.run.progress_guard) and the loop-lag monitor (host.run.loop_lag), on a
virtual clock: the guard's decisions and the monitor's numbers, with no wall time involved."""

from __future__ import annotations

from collections.abc import Callable

import anyio
import pytest

from host.run.loop_lag import LagMonitor
from host.run.progress_guard import ProgressGuard, Stall


class VirtualClock:
    """A clock that moves only when ``sleep`` is awaited (by the asked seconds plus ``extra()``)."""

    def __init__(self, extra: Callable[[], float] = lambda: 0.0) -> None:
        self.now = 0.0
        self.extra = extra

    def __call__(self) -> float:
        return self.now

    async def sleep(self, s: float) -> None:
        self.now += s + self.extra()
        await anyio.lowlevel.checkpoint()


def _guard(clock: VirtualClock, probes: dict[str, Callable[[], object]], phase: Callable[[], str | None],
           stalls: list[Stall], limit_s: float = 5.0) -> ProgressGuard:
    return ProgressGuard(probes, phase, lambda: "wait[0]/pick[0] to end", stalls.append,  # type: ignore[arg-type]
                         limit_s=limit_s, check_s=0.25, clock=clock, sleep=clock.sleep)


def test_nothing_moving_for_the_limit_is_one_stall_naming_the_phase_and_the_wait() -> None:
    clock, stalls = VirtualClock(), []
    guard = _guard(clock, {"board time": lambda: 10.5, "frames sent": lambda: 400}, lambda: "running the turn", stalls)
    stall = anyio.run(guard.run, backend="asyncio")
    assert stalls == [stall] and guard.stall is stall
    assert 5.0 <= stall.waited_s < 5.3 and 5.0 <= clock.now < 5.6
    assert stall.message.startswith("no progress for 5 s of wall time while running the turn, waiting for wait[0]/pick[0] to end")
    assert "board time 10.500 s" in stall.message and "frames sent 400" in stall.message


def test_any_probe_that_moves_keeps_the_guard_quiet() -> None:
    clock, stalls = VirtualClock(), []

    def slow_frames() -> int:  # one frame every 4 s of wall time: slow, but progress
        return int(clock.now // 4)

    guard = _guard(clock, {"board time": lambda: 1.0, "frames sent": slow_frames}, lambda: "moving to the start pose", stalls)

    async def main() -> None:
        with anyio.CancelScope() as scope:
            sleep = clock.sleep

            async def sleep_until_two_minutes(s: float) -> None:
                if clock.now > 120:
                    scope.cancel()
                await sleep(s)

            guard.sleep = sleep_until_two_minutes
            await guard.run()

    anyio.run(main, backend="asyncio")
    assert clock.now > 120 and stalls == []


def test_a_disarmed_guard_never_stalls_and_rearming_restarts_the_wait() -> None:
    clock, stalls = VirtualClock(), []
    guard = _guard(clock, {"board time": lambda: 1.0}, lambda: None if clock.now < 100 else "settling after the turn", stalls)
    stall = anyio.run(guard.run, backend="asyncio")
    assert stall.phase == "settling after the turn"
    assert 105.0 <= clock.now < 105.6  # the wait counted from the arming at 100 s, not from the start


def test_a_starved_process_is_not_counted_as_no_progress() -> None:
    gaps = iter([30.0] + [0.0] * 10_000)  # the process did not run for 30 s once (a suspended host)
    clock, stalls = VirtualClock(lambda: next(gaps)), []
    stall = anyio.run(_guard(clock, {"board time": lambda: 1.0}, lambda: "running the turn", stalls).run, backend="asyncio")
    assert stall.waited_s < 5.3 and clock.now >= 35.0


def test_bad_limits_are_refused() -> None:
    with pytest.raises(ValueError):
        ProgressGuard({}, lambda: None, lambda: "", lambda s: None, limit_s=0)


def test_lag_monitor_reports_quantiles_and_the_max_over_a_bounded_window() -> None:
    lags = iter([0.0001] * 98 + [0.004, 0.050] + [0.0002] * 300)
    clock = VirtualClock(lambda: next(lags))
    monitor = LagMonitor(period_s=0.005, window=100, clock=clock, sleep=clock.sleep)

    async def sample(n: int) -> None:
        for _ in range(n):
            before = monitor.clock()
            await monitor.sleep(monitor.period_s)
            monitor.add(monitor.clock() - before - monitor.period_s)

    anyio.run(sample, 100, backend="asyncio")
    stats = monitor.stats()
    assert stats["n"] == 100 and stats["period_ms"] == 5.0
    assert stats["p50_ms"] == pytest.approx(0.1, abs=1e-3) and stats["max_ms"] == pytest.approx(50.0, abs=1e-3)
    assert 4.0 <= stats["p99_ms"] <= 50.0
    anyio.run(sample, 300, backend="asyncio")  # the window keeps the newest 100; the max stays the run's
    stats = monitor.stats()
    assert stats["n"] == 400 and stats["p99_ms"] == pytest.approx(0.2, abs=1e-3) and stats["max_ms"] == pytest.approx(50.0, abs=1e-3)
    assert len(monitor._ring) == 100
    monitor.reset()
    assert monitor.stats() == {"p50_ms": None, "p99_ms": None, "max_ms": None, "n": 0, "period_ms": 5.0}


def test_lag_monitor_run_samples_the_real_loop() -> None:
    monitor = LagMonitor(period_s=0.001)

    async def main() -> None:
        async with anyio.create_task_group() as tg:
            tg.start_soon(monitor.run)
            while monitor.samples < 20:
                await anyio.lowlevel.checkpoint()
            tg.cancel_scope.cancel()

    anyio.run(main, backend="asyncio")
    stats = monitor.stats()
    assert stats["n"] >= 20 and 0.0 <= stats["p50_ms"] <= stats["p99_ms"] <= stats["max_ms"]
