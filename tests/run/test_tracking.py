"""host.run.tracking.recovery on hand-made traces: when tracking is back within the bound for good."""

from __future__ import annotations

import numpy as np
import pytest

from host.run.tracking import TrackingTrace, recovery, resume_times


def trace(worst: list[float], dt: float = 0.02) -> TrackingTrace:
    err = np.tile(np.asarray(worst, dtype=float)[:, None] / 2, (1, 12))
    err[:, 3] = worst  # servo 3 is the worst one
    return TrackingTrace(np.arange(len(worst)) * dt, err, np.zeros(len(worst), dtype=np.int64))


def test_recovery_counts_to_the_first_report_after_the_last_excursion() -> None:
    tr = trace([0.5, 0.5, 6.0, 2.0, 4.0, 1.0, 1.0, 1.5])
    rec = recovery(tr, after_s=0.03)  # reports from t = 0.04 on
    assert rec.seconds == pytest.approx(0.10 - 0.03)  # back below 3 deg at 0.10 s, after the 4 deg at 0.08 s
    assert rec.peak_deg == 6.0 and rec.after_deg == 1.5


def test_never_recovered_and_already_tracking() -> None:
    assert recovery(trace([1.0, 5.0, 4.0]), after_s=0.0).seconds is None
    ok = recovery(trace([9.0, 1.0, 1.0]), after_s=0.01)  # the bad report is before the fault ended
    assert ok.seconds == pytest.approx(0.01) and ok.peak_deg == 1.0
    nan = trace([1.0, 1.0])
    nan.err_deg[1, :] = np.nan  # nothing commanded yet counts as not tracking
    assert recovery(nan, 0.0).seconds is None
    with pytest.raises(ValueError, match="no report"):
        recovery(trace([1.0]), after_s=5.0)


def test_resume_lines_are_read_from_the_board_stderr() -> None:
    err = ("board: watchdog hold at board time 2.222000 s, 0.202000 s after the last valid message\n"
           "board: watchdog resume at board time 2.630000 s, a valid message ended the hold after 0.408000 s\n")
    assert resume_times(err) == [(2.63, 0.408)]
