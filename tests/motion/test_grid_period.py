"""The frame grid over a modelled line (:func:`host.motion.streamer.grid_period_us`)."""

from __future__ import annotations

import pytest

from host.motion.streamer import (GRID_LINE_SHARE, GRID_PERIOD_US, SLOW_GRID_LINE_SHARE, frame_wire_bytes,
                                  grid_period_us, slow_line)
from protocol.wiremodel import BITS_PER_BYTE, MAX_BAUD


def test_a_line_fast_enough_keeps_the_100_hz_grid() -> None:
    assert grid_period_us(12, None) == grid_period_us(12, MAX_BAUD) == grid_period_us(12, 115_200) == GRID_PERIOD_US


@pytest.mark.parametrize(("baud", "period_us"), [(57_600, 20_000), (19_200, 50_000), (9_600, 60_000), (2_400, 210_000)])
def test_coco_on_slow_lines(baud: int, period_us: int) -> None:
    assert grid_period_us(12, baud) == period_us


@pytest.mark.parametrize("n_servos", [1, 4, 12, 24, 32])
@pytest.mark.parametrize("baud", [300, 1_200, 9_600, 19_200, 57_600, 78_000, 115_200, 1_000_000])
def test_the_grid_fills_at_most_its_share_of_the_line_and_no_less_period_would(n_servos: int, baud: int) -> None:
    frame_s = frame_wire_bytes(n_servos) * BITS_PER_BYTE / baud
    period = grid_period_us(n_servos, baud)
    share = SLOW_GRID_LINE_SHARE if slow_line(n_servos, baud) else GRID_LINE_SHARE  # a slow line: no heartbeats
    assert period % GRID_PERIOD_US == 0
    assert frame_s <= share * period * 1e-6 + 1e-12
    if period > GRID_PERIOD_US:  # the smallest such multiple
        assert frame_s > share * (period - GRID_PERIOD_US) * 1e-6
