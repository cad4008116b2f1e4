"""An external interruption mid-task: the moving calls stop smoothly, nothing queued runs, servos settle.

Both clocks are checked: lockstep cuts at the first frame not yet sent (a
lockstep board simulates every frame it has before it reads a FLUSH), realtime
a couple of frames ahead of the board clock, dropping the ~60 ms of frames the
board holds beyond the cut. Either way the host sends FLUSH for the servos of
each interrupted channel (head and body), seen here in the host's frame log.
"""

from __future__ import annotations

import json

import numpy as np

from robots.coco.motions import channel_servos

from .conftest import E2ERun, mask_of, run_e2e
import pytest

PROGRAM = '<head_act action="nod"><move_strides direction="forward" times="6"/></head_act><wave/>'
INTERRUPT_AT = 1.5  # board seconds after the stream starts: the strides are under way, the wave is queued


def check_interrupted(run: E2ERun) -> None:
    res, s = run.report.result, run.report.summary
    assert res.interrupted and s.outcome == "interrupted"
    nod, strides, wave = run.one("head_act"), run.one("move_strides"), run.one("wave")
    # the queued call never ran
    assert wave.start is None and wave.outcome in ("cancelled", "interrupted"), run.table()
    # the moving calls were interrupted and came to rest soon after the interruption
    t_int = run.t0 + INTERRUPT_AT
    for c in (nod, strides):
        assert c.outcome == "interrupted", run.table()
        assert c.start < t_int < c.end <= t_int + 0.5, run.table()
    assert not s.fell and s.max_tilt_deg < 30
    # the servos settle: nothing moves in the last 0.2 s of telemetry
    t, q, v = run.telemetry
    tail = (t >= t.max() - 0.2)
    assert np.abs(v[tail]).max() < 0.1, f"servos still moving at {np.abs(v[tail]).max():.3f} rad/s"
    assert np.abs(q[tail] - q[-1]).max() < np.radians(1.0)
    # the queued wave never moved anything: after the stop the legs hold where the strides stopped
    late = t > strides.end + 0.1
    legs = list(channel_servos("body"))
    assert np.degrees(np.ptp(q[late][:, legs], axis=0)).max() < 2.0


def test_interrupt_lockstep(tmp_path) -> None:
    run = run_e2e(PROGRAM, tmp_path, interrupt_at=INTERRUPT_AT)
    check_interrupted(run)
    check_flushed(run)
    doc = json.loads((tmp_path / "timeline.json").read_text())
    assert [c["outcome"] for c in doc["calls"]] == ["interrupted"] * 3


@pytest.mark.realtime
def test_interrupt_realtime_flushes(tmp_path) -> None:
    """Same run on the wall clock (about 3 s): the buffered frames of the head and body are flushed."""
    run = run_e2e(PROGRAM, tmp_path, interrupt_at=INTERRUPT_AT, lockstep=False)
    check_interrupted(run)
    check_flushed(run)


def check_flushed(run: E2ERun) -> None:
    """FLUSH for the head and the body servos, from the cut just after the interruption.

    (A realtime board also gets a FLUSH at each call's start, replacing the hold already sent
    for the servos the call takes over: those come before the interruption.)"""
    t_int_us = (run.t0 + INTERRUPT_AT) * 1e6
    flushes = [f for f in run.host_sent("FLUSH") if f["from_us"] >= t_int_us]
    masks = {f["mask"] for f in flushes}
    assert mask_of(channel_servos("body")) in masks and mask_of(channel_servos("head")) in masks, flushes
    assert all(f["from_us"] <= t_int_us + 300_000 for f in flushes), flushes
