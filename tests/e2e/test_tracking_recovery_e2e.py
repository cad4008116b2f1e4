"""Tracking recovers after a short link cut, over serial (pty) and over CAN (SLCAN on a pty).

A REALTIME board: ``cut=START+LENGTH`` counts wall seconds from the first unit on each direction
(:class:`protocol.faults.FaultInjector` gets ``time.monotonic()``), which on a realtime board is board
time. On a lockstep board the same cut is no fault the board can see: while nothing reaches it,
nothing ADVANCEs it, so its clock stands still instead of running into the watchdog (and a lockstep
run is often over before START wall seconds have passed).

The cut (0.6 s) is shorter than watchdog + crouch delay: the board HOLDs 0.2 s into it, the first
valid message after it ends the hold (the board's ``board: watchdog resume at board time T s``
line) and the host's stream, which kept its timeline through the cut, takes over again. Measured
from the board's own frame log (:mod:`host.run.tracking`): the time from that resume until every
servo is within 3 deg of the target of the last frame the board applied, and stays there (asserted
for 1 s; printed to the end of the run). No sleeps: each run ends when the program is done.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from firmware_sim.config import BoardConfig
from host.run.tracking import find_board_log, recovery, recovery_after_hold, tracking_trace
from protocol.messages import FaultFlags
from support.realtime_lock import realtime_part_done

from .conftest import run_e2e

pytestmark = pytest.mark.realtime  # tests/support/realtime_lock.py

PROGRAM = '<move_strides direction="forward" times="8"/>'  # ~5.5 s of walking: the cut falls inside it
CUT_START_S, CUT_LEN_S = 3.0, 0.6
BOUND_DEG = 3.0
#: tracking must be back within BOUND_DEG this soon after the first valid message: the board's
#: resume blend takes <= 0.4 s at every gait phase (tests/firmware/test_resume_after_hold.py asserts
#: < 0.5 s deterministically); a realtime board on a loaded 2-core machine adds scheduling stalls
#: (once 0.79 s measured under load before the blend), hence the margin here
RECOVER_S = 1.0
#: and it stays within BOUND_DEG for this long after the resume
STAY_S = 1.0
#: the longest resume blend at any gait phase (s, see RECOVER_S): no servo may be clamped within it
BLEND_S = 0.4


@pytest.mark.parametrize("link", ["pty", "can:slcan:pty"])
def test_tracking_recovers_after_a_short_cut(tmp_path: Path, link: str) -> None:
    run = run_e2e(PROGRAM, tmp_path, lockstep=False, link=link, faults=f"cut={CUT_START_S:g}+{CUT_LEN_S:g}")
    realtime_part_done()  # the board has stopped; reading its log back (~2 s) needs no machine to itself
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["outcome"] == "done" and {c.outcome for c in run.calls} == {"done"}, run.table()
    watchdog_s = BoardConfig().watchdog_ms / 1000
    # the cut's hold (over SLCAN the HELLO exchange may make the board hold briefly before the walk)
    resumed_at, held_s, _ = recovery_after_hold(tmp_path, BOUND_DEG, not_before_s=CUT_START_S)
    assert abs(held_s - (CUT_LEN_S - watchdog_s)) < 0.1, (held_s, (tmp_path / "board.stderr").read_text()[-2000:])
    walk = run.one("move_strides")
    assert walk.start is not None and walk.end is not None
    assert walk.start < resumed_at - held_s and resumed_at + STAY_S < walk.end, run.table()  # inside the walk

    trace = tracking_trace(find_board_log(tmp_path))
    before = (trace.t > resumed_at - held_s - 0.5) & (trace.t < resumed_at - held_s)
    assert before.any() and float(max(trace.worst_deg[before])) < BOUND_DEG  # it tracked before the cut
    # back within the bound for good over the next STAY_S (a realtime board on a loaded machine may
    # overrun ticks later in the walk; that is not this fault's recovery)
    rec = recovery(trace, resumed_at, BOUND_DEG, until_s=resumed_at + STAY_S)
    to_end = recovery(trace, resumed_at, BOUND_DEG)
    print(f"\n{link}: hold ended at board time {resumed_at:.3f} s after {held_s:.3f} s; tracking within "
          f"{BOUND_DEG:g} deg {rec.seconds if rec.seconds is None else round(rec.seconds, 3)} s later "
          f"(to the end of the run: {to_end.seconds if to_end.seconds is None else round(to_end.seconds, 3)} s); "
          f"peak {rec.peak_deg:.2f} deg after the cut, worst {to_end.after_deg:.2f} deg after recovery")
    assert rec.seconds is not None, f"tracking never came back within {BOUND_DEG} deg: {rec}"
    assert rec.seconds < RECOVER_S, rec
    # the resume from the held pose blends within the servos' speed limits (no clamped jump). Over its
    # blend only: later in the walk a starved realtime board catching up on overrun ticks may clamp
    # (once in CI: 138 overruns, one CLAMPED report 0.48 s after the resume, tracking back at 0.18 s)
    after = (trace.t >= resumed_at) & (trace.t <= resumed_at + max(BLEND_S, rec.seconds))
    assert not any(int(f) & FaultFlags.CLAMPED for f in trace.faults[after])
