"""The run's timing health line (host.run.link_health.timing_health_line) from summary.json's extra.timing."""

from __future__ import annotations

from host.run.link_health import timing_health_line


def test_the_line_gives_the_lag_quantiles_with_n_and_every_count() -> None:
    extra = {"timing": {"lag": {"p50_ms": 0.214, "p99_ms": 1.3, "max_ms": 230.644, "n": 12345, "period_ms": 5.0},
                        "frames_late": 3, "frames_skipped": 0, "watchdog_trips": 2, "recording_dropped": 7,
                        "stop_overdue": False}}
    assert timing_health_line(extra) == ("timing: control-path lag p50 0.21 ms, p99 1.30 ms, max 230.64 ms (n 12 345); "
                                         "3 frames late, 0 skipped; 2 board watchdog trips; 7 recording drops")


def test_unknown_counts_and_an_overdue_stop_are_said() -> None:
    extra = {"timing": {"lag": {"p50_ms": None, "p99_ms": None, "max_ms": None, "n": 0},
                        "frames_late": None, "frames_skipped": None, "watchdog_trips": None, "recording_dropped": 0,
                        "stop_overdue": True}}
    line = timing_health_line(extra)
    assert line is not None
    assert line.startswith("timing: control-path lag not measured; ? frames late, ? skipped; ? board watchdog trips")
    assert line.endswith("; the stop's deadline cut the work")


def test_a_summary_without_timing_has_no_line() -> None:
    assert timing_health_line({}) is None and timing_health_line({"timing": None}) is None


def test_injected_stalls_are_named_in_the_line() -> None:
    extra = {"timing": {"lag": {"p50_ms": 0.3, "p99_ms": 900.0, "max_ms": 1000.0, "n": 10}, "frames_late": 0,
                        "frames_skipped": 0, "watchdog_trips": 0, "recording_dropped": 0, "stop_overdue": False,
                        "stalls_injected": {"count": 4, "total_s": 2.5}}}
    line = timing_health_line(extra)
    assert line is not None and line.endswith("; 4 control-path stalls injected (2.5 s, GHOSTSHELL_STALLS)")
