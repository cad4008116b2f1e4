"""A start's first frame is due after the host's own send path too (``FrameStreamer.send_path_us``), planned
for a quick arrival (``FrameStreamer.start_due_us``) within a slack of the sure one (``soonest_us``).

The TIME_SYNC uplink is measured from the moment a request is written; a new call's first frame is
still to be sampled and built after its due time is chosen. ``bench/bench_latency.py`` found 13 of
51 first messages on the board after their due time (applied a tick late) before the send path counted. These
drive the streamer through a recording link with a fixed board clock, so the arithmetic is exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import anyio
import numpy as np

from host.motion.mixer import Mixer
from host.motion.streamer import (
    SEND_PATH_DEFAULT_US,
    SEND_PATH_WINDOW,
    START_QUANTILE,
    START_SLACK_US,
    FrameStreamer,
)
from protocol.messages import ServoFrame
from support.frame_link import TICK_US, Ramp, RecordingLink


def _streamer(link: RecordingLink) -> FrameStreamer:
    s = FrameStreamer(link, Mixer(np.zeros(4)))  # type: ignore[arg-type]
    s.next_us = link.now_us + 60_000  # the 60 ms lookahead already sent
    return s


def _ceil_tick(t: int) -> int:
    return -(-t // TICK_US) * TICK_US


def test_before_any_start_the_default_send_path_is_in_the_margin() -> None:
    link = RecordingLink()
    s = _streamer(link)
    assert s.send_path_us() == SEND_PATH_DEFAULT_US
    assert s.soonest_us() == _ceil_tick(link.now_us + link.uplink_us + SEND_PATH_DEFAULT_US)


def test_the_margin_is_a_high_quantile_of_the_measured_send_paths() -> None:
    link = RecordingLink()
    s = _streamer(link)
    for us in range(100, 100 + 100 * SEND_PATH_WINDOW, 100):  # 32 starts of 0.1 .. 3.2 ms
        s._send_path_s.append(us * 1e-6)
    assert s.send_path_us() == 2_900  # the 0.9 quantile: the 29th of 32 (index int(0.9 * 32))
    assert s.soonest_us() == _ceil_tick(link.now_us + link.uplink_us + 2_900)
    s._send_path_s.append(10e-3)  # one slow start (10 ms): the oldest (0.1 ms) leaves the window
    assert s.send_path_us() == 3_000  # one outlier moves the margin by one rank, not to 10 ms
    link.lockstep = True  # lockstep: the first unsent frame, whatever the link
    assert s.soonest_us() == s.next_us


def test_a_start_measures_its_send_path_and_is_due_after_it() -> None:
    link = RecordingLink()
    s = _streamer(link)

    async def main() -> None:
        seg = await s.start_now(Ramp(), "nod")
        assert seg.first_frame_us == _ceil_tick(link.now_us + link.uplink_us + SEND_PATH_DEFAULT_US)
        # the first frame, due then, and after it a FLUSH of its servos from just after that time
        assert isinstance(link.sent[0], ServoFrame) and link.sent[0].apply_at_us == seg.first_frame_us
        assert link.sent[1] == ("FLUSH", seg.first_frame_us + 1, 0b11)

    anyio.run(main)
    assert len(s._send_path_s) == 1 and 0 < s._send_path_s[0] < 1.0  # measured on the wall clock
    assert s.send_path_us() == round(s._send_path_s[0] * 1e6)


@dataclass
class _SpreadLink(RecordingLink):
    """An uplink of 200 µs at the 0th quantile rising by ``spread_us`` to the 100th."""

    spread_us: int = 1_000

    def latency_us(self, nbytes: int = 0, q: float = 0.99) -> int:
        return 200 + round(self.spread_us * q)


def _quick_streamer(link: RecordingLink) -> FrameStreamer:
    s = _streamer(link)
    for k in range(SEND_PATH_WINDOW):  # 32 starts of 0.20 .. 0.51 ms
        s._send_path_s.append((200 + 10 * k) * 1e-6)
    return s


def test_a_start_is_planned_for_a_quick_arrival_not_a_sure_one() -> None:
    """``soonest_us`` (what surely arrives: the p99 uplink, the 0.9 send path) stays for the grid; a start
    is due at the tick after a quick arrival (``START_QUANTILE`` of both), since the board applies a
    later arrival at its next tick anyway (tests/firmware/test_board_core.py)."""
    link = _SpreadLink(now_us=1_001_000)  # the two plans fall on different ticks
    s = _quick_streamer(link)
    quick_send = 200 + 10 * int(START_QUANTILE * SEND_PATH_WINDOW)
    assert s.send_path_us(START_QUANTILE) == quick_send < s.send_path_us() == 200 + 10 * 28
    due = s.start_due_us()
    assert due == _ceil_tick(link.now_us + 200 + round(1_000 * START_QUANTILE) + quick_send)
    assert due < s.soonest_us() == _ceil_tick(link.now_us + 200 + 990 + 480)

    async def main() -> None:
        seg = await s.start_now(Ramp(), "nod")
        assert seg.first_frame_us == link.sent[0].apply_at_us == due  # type: ignore[union-attr]

    anyio.run(main)
    link.lockstep = True
    assert s.start_due_us() == s.next_us


def test_over_a_jittery_link_a_start_is_planned_at_most_a_slack_before_the_sure_arrival() -> None:
    """A ``delay=80±20`` fault spreads arrivals over 40 ms, twice the board's ``max_late_us``: planned for
    the quick arrival, every slow one would be refused as LATE. The plan stays within
    ``START_SLACK_US`` of the sure one."""
    link = _SpreadLink(spread_us=40_000)
    s = _quick_streamer(link)
    sure = link.now_us + 200 + round(40_000 * 0.99) + s.send_path_us()
    assert s.soonest_us() == _ceil_tick(sure)
    assert s.start_due_us() == _ceil_tick(sure - START_SLACK_US)


def test_the_start_slack_leaves_half_the_boards_late_window_beyond_the_p99() -> None:
    """A start planned ``START_SLACK_US`` before the sure arrival and arriving by the uplink p99 is at most
    that late; the board's ``max_late_us`` must leave as much again for arrivals beyond the p99, or the
    first slow one is refused as LATE (the Python board's and the C firmware's default, 20 ms)."""
    from firmware_sim.config import BoardConfig

    assert 0 < START_SLACK_US <= BoardConfig().max_late_us // 2
