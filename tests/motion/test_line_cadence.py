"""A slow line's cadence (host.motion.line_cadence) and what the streamer does with it (issue 46).

On a line whose frame grid outgrows the board's 200 ms watchdog the handshake raises the watchdog past
the grid and lowers the report rate; the grid's frames carry only the servos that move; a lockstep
top-up reaches past the board's next report; a line too slow for the robot's slowest reports is refused.
Driven through a recording link (``tests/support/frame_link.py``): the arithmetic is exact.
"""

from __future__ import annotations

import anyio
import numpy as np
import pytest

from host.motion.line_cadence import (BOARD_WATCHDOG_MS, LineCadence, LineTooSlow, line_cadence,
                                      report_pair_bytes)
from host.motion.mixer import Mixer
from host.motion.streamer import WATCHDOG_GRID_PERIODS, FrameStreamer, slow_line
from protocol.messages import ConfigKey, ServoFrame
from protocol.wiremodel import BITS_PER_BYTE

from support.frame_link import Ramp, RecordingLink


def test_coco_at_2400_baud_gets_a_watchdog_past_its_grid_and_reports_the_line_carries() -> None:
    c = line_cadence(12, 2_400)
    assert c == LineCadence(210_000, 1_220, 1)
    assert c.config() == ((ConfigKey.WATCHDOG_MS, 1_220), (ConfigKey.TELEMETRY_RATE_HZ, 1))  # watchdog first
    heartbeat_s = c.heartbeat_s()
    assert heartbeat_s is not None and heartbeat_s * 1e6 > c.period_us  # no heartbeat while the grid streams


@pytest.mark.parametrize("baud", [None, 115_200, 57_600, 19_200, 14_400])
def test_a_line_the_default_watchdog_covers_changes_nothing(baud: int | None) -> None:
    c = line_cadence(12, baud)
    assert not slow_line(12, baud) and c.config() == () and c.heartbeat_s() is None
    assert WATCHDOG_GRID_PERIODS * c.period_us <= BOARD_WATCHDOG_MS * 1000


@pytest.mark.parametrize("n_servos", [2, 6, 12, 16, 32])
@pytest.mark.parametrize("baud", [2_400, 4_800, 9_600, 12_000])
def test_a_slow_lines_watchdog_covers_three_periods_and_a_nudge_and_its_reports_fit(n_servos: int, baud: int) -> None:
    try:
        c = line_cadence(n_servos, baud)
    except LineTooSlow:
        assert n_servos > 12 and baud == 2_400  # a 32-servo report pair alone is more than 2 400 bit/s
        return
    if c.watchdog_ms is None:
        return
    hz = c.telemetry_hz or 50
    assert c.watchdog_ms * 1000 >= WATCHDOG_GRID_PERIODS * c.period_us
    assert c.watchdog_ms * 1000 >= c.period_us + 1_000_000 // hz + 2_000  # a lockstep nudge: a report period
    assert hz == 1 or hz * report_pair_bytes(n_servos) * BITS_PER_BYTE <= 0.5 * baud


@pytest.mark.parametrize("baud", [300, 1_200])
def test_a_line_too_slow_for_the_robot_is_refused_naming_the_rate_that_works(baud: int) -> None:
    with pytest.raises(LineTooSlow, match=f"--baud {baud} is too slow for a 12-servo robot.*use --baud 2400 or more"):
        line_cadence(12, baud)


def _frames(link: RecordingLink) -> list[ServoFrame]:
    return [m for m in link.sent if isinstance(m, ServoFrame)]


def test_sparse_grid_frames_carry_only_the_servos_that_move() -> None:
    link = RecordingLink(now_us=0, lockstep=True)
    s = FrameStreamer(link, Mixer(np.zeros(4)), period_us=50_000, lookahead_us=500_000, sparse=True)  # type: ignore[arg-type]
    s.add(Ramp(servos=(2, 3)), "ramp", start_us=200_000)  # 0 -> 0.5 rad over 0.2 s
    anyio.run(s.top_up, 0)
    masks = {f.apply_at_us: f.mask for f in _frames(link)}
    assert masks[50_000] == 0b1111  # the first frame: every servo
    assert masks[100_000] == 0b0001  # nothing moves: servo 0 alone (a frame needs one)
    assert masks[150_000] == 0b0001
    # the ramp's servos from its start (0 rad at 0.2 s, where their straight segment starts) to its end
    assert all(masks[t] == 0b1100 for t in range(200_000, 400_001, 50_000)), masks
    assert masks[450_000] == masks[500_000] == 0b0001  # arrived and held: left out
    full = RecordingLink(now_us=0, lockstep=True)
    s = FrameStreamer(full, Mixer(np.zeros(4)), period_us=50_000, lookahead_us=500_000)  # type: ignore[arg-type]
    anyio.run(s.top_up, 0)
    assert {f.mask for f in _frames(full)} == {0b1111}  # a fast line: full-body frames, as before


class _ReportingLink(RecordingLink):
    def report_period_us(self) -> int:
        return 1_002_000  # 1 Hz reports and a tick


def test_a_lockstep_top_up_reaches_past_the_next_report() -> None:
    link = _ReportingLink(now_us=0, lockstep=True)
    s = FrameStreamer(link, Mixer(np.zeros(4)), period_us=210_000, sparse=True)  # type: ignore[arg-type]
    anyio.run(s.top_up, 1_000_000)
    # the board runs as far as the frames reach: past its next report (2.0 s), not 60 ms past this one
    assert max(f.apply_at_us for f in _frames(link)) >= 1_000_000 + 1_002_000
