"""Tracking after a short cut, on the lockstep board core, at every phase of the walking gait.

A host streams ``move_strides`` the way :class:`host.motion.streamer.FrameStreamer` does (one
full-body SERVO_FRAME every 10 ms of board time, 60 ms ahead) and keeps its timeline through a cut:
the frames due to be sent during the cut are lost. The board HOLDs 200 ms into the silence; the
first frame after the cut ends the hold and the board blends from the held pose into the stream
(``Board._resume`` / ``TargetStream.blend``: minimum jerk at ``BoardConfig.resume_speed``). Before the blend
the board ramped to the first frame within the lookahead, which hit the servo speed limit (CLAMPED)
at some phases of 0.3 s and 1.1 s cuts: the CLAMPED assertion below is that failing case.
Deterministic (board time only, no link, no wall clock), so every gait phase is tried; the realtime
e2e runs over serial and SLCAN (``tests/e2e/test_tracking_recovery_e2e.py``) sample a few phases
under real scheduling.

Measured as in :mod:`host.run.tracking`: at each 50 Hz TELEMETRY, every servo against the target
of the last frame the board applied; recovery = from the first frame after the cut until the error
stays below 3 deg.
"""

from __future__ import annotations

import numpy as np
import pytest

from firmware_sim.board import Board
from firmware_sim.config import BoardConfig
from firmware_sim.safety import Mode
from protocol.messages import FaultFlags, ServoFrame, Telemetry
from robots.coco.gaits import move_strides, walk_params

PERIOD_US, LOOKAHEAD_US = 10_000, 60_000
WALK_AT_US = 500_000  # the walk's first target is due here (the stand pose before)
BOUND_DEG, RECOVER_S, TAIL_S = 3.0, 0.5, 1.2


def cut_run(cut_start_s: float, cut_len_s: float) -> tuple[float, float, bool]:
    """Walk, cut the host->board stream for ``cut_len_s`` from board time ``cut_start_s``; returns
    (recovery s from the first frame after the cut, peak error deg after it, any CLAMPED after it)."""
    board = Board(BoardConfig(lockstep=True))
    stand = np.array(board.table.neutral)
    walk = move_strides(stand, times=8)
    body = list(walk.servos)
    sent: dict[int, np.ndarray] = {}
    seq, held, resumed = 1, False, None
    cut0, cut1 = round(cut_start_s * 1e6), round((cut_start_s + cut_len_s) * 1e6)
    end = cut1 + round(TAIL_S * 1e6)
    reports: list[tuple[int, float, int]] = []
    while board.now_us < end:
        now = board.now_us
        if now % PERIOD_US == 0 and not cut0 <= now < cut1:
            at = now + LOOKAHEAD_US
            q = stand.copy()
            q[body] = walk.at(max(0.0, (at - WALK_AT_US) / 1e6))
            board.handle(ServoFrame(at, 0x0FFF, tuple(float(v) for v in q)), seq)
            sent[seq] = q
            seq += 1
            if held and resumed is None:
                assert board.mode is Mode.RUN, "the first frame after the cut did not end the hold"
                resumed = now
        held = held or board.mode is Mode.HOLD
        for msg in board.tick():
            if isinstance(msg, Telemetry) and msg.last_applied_seq in sent:
                err = np.degrees(np.abs(np.asarray(msg.positions) - sent[msg.last_applied_seq])).max()
                reports.append((msg.board_time_us, float(err), int(msg.faults)))
    assert held and resumed is not None, "the cut never made the board hold"
    after = [(t, e, f) for t, e, f in reports if t >= resumed]
    bad = [i for i, (_, e, _) in enumerate(after) if not e < BOUND_DEG]
    assert not bad or bad[-1] < len(after) - 1, f"never back within {BOUND_DEG} deg"
    back_at = after[bad[-1] + 1][0] if bad else after[0][0]
    clamped = any(f & FaultFlags.CLAMPED for _, _, f in after)
    return (back_at - resumed) / 1e6, max(e for _, e, _ in after), clamped


@pytest.mark.parametrize(("cut_len_s", "phases"), [(0.6, 35), (0.3, 7), (1.1, 7)])
def test_tracking_recovers_after_a_cut_at_every_gait_phase(cut_len_s: float, phases: int) -> None:
    period, _ = walk_params()
    starts = [1.5 + k * period / phases for k in range(phases)]  # the walk is under way from 0.5 s
    results = [cut_run(s, cut_len_s) for s in starts]
    times = np.array([r[0] for r in results])
    peaks = np.array([r[1] for r in results])
    print(f"\ncut {cut_len_s} s at {phases} gait phases: back within {BOUND_DEG:g} deg after median "
          f"{np.median(times):.3f} s, max {times.max():.3f} s; peak error median {np.median(peaks):.1f} deg, "
          f"max {peaks.max():.1f} deg")
    assert times.max() < RECOVER_S, dict(zip(starts, times))
    assert not any(r[2] for r in results), "the resume from the held pose was clamped to a servo limit"
