"""A start's first frame is due after the host's own send path too (``FrameStreamer.send_path_us``).

The TIME_SYNC uplink is measured from the moment a request is written; a new call's first frame is
still to be sampled and built after its due time is chosen. ``bench/bench_latency.py`` found 13 of
51 first messages on the board after their due time (applied a tick late) before the send path counted. These
drive the streamer through a recording link with a fixed board clock, so the arithmetic is exact.
"""

from __future__ import annotations

import anyio
import numpy as np

from host.motion.mixer import Mixer
from host.motion.streamer import SEND_PATH_DEFAULT_US, SEND_PATH_WINDOW, FrameStreamer
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
        assert link.sent[0] == ("FLUSH", seg.first_frame_us, 0b11)  # then the first frame, due then
        assert isinstance(link.sent[1], ServoFrame) and link.sent[1].apply_at_us == seg.first_frame_us

    anyio.run(main)
    assert len(s._send_path_s) == 1 and 0 < s._send_path_s[0] < 1.0  # measured on the wall clock
    assert s.send_path_us() == round(s._send_path_s[0] * 1e6)
