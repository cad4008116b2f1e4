"""A realtime streamer never sends a grid frame that can no longer reach the board in time.

The streamer fixes its first frame time when it is made; a host that stalls longer than one period
before its first top-up (or longer than the lookahead later) used to send the frames it had missed,
and the board NACKed them LATE (``tests/link/test_paced_link.py`` failed so under overload in CI).
Now a top-up starts at the first grid time a frame sent now can reach (board clock + uplink p99 +
the send path), samples the mix there and counts the rest in ``frames_skipped``. Driven through
a recording link (``tests/support/frame_link.py``) with a fixed board clock, so the arithmetic is exact.
"""

from __future__ import annotations

import anyio
import numpy as np

from host.motion.mixer import Mixer
from host.motion.streamer import SEND_PATH_DEFAULT_US, FrameStreamer, frame_wire_bytes
from protocol.messages import ServoFrame

from support.frame_link import Ramp, RecordingLink

PERIOD_US = 10_000


def _frames(link: RecordingLink) -> list[ServoFrame]:
    return [m for m in link.sent if isinstance(m, ServoFrame)]


def test_after_a_stall_the_first_frame_sent_is_the_first_still_in_reach() -> None:
    link = RecordingLink(now_us=1_000_000)
    s = FrameStreamer(link, Mixer(np.zeros(4)))  # type: ignore[arg-type]
    first_planned = s.first_free_us
    assert first_planned == 1_010_000
    seg = s.add(Ramp(), "ramp", start_us=1_020_000)  # begins inside the stall
    link.now_us = 1_095_000  # the host stalled 95 ms before its first top-up
    anyio.run(s.top_up)
    sent = _frames(link)
    reach = link.now_us + link.uplink_us + SEND_PATH_DEFAULT_US
    assert sent and sent[0].apply_at_us == -(-reach // PERIOD_US) * PERIOD_US == 1_100_000
    assert all(f.apply_at_us >= reach for f in sent)  # nothing the board would NACK LATE
    assert (1_100_000 - first_planned) // PERIOD_US == 9
    assert s.frames_skipped == 0  # before the first frame the grid only starts later: the board expected nothing
    # the segment that began in the gap is started by the first frame sent, sampled where it stands then
    assert seg.first_frame_us == 1_100_000
    np.testing.assert_allclose(sent[0].targets[:2], [0.5 * 0.08 / 0.2] * 2)
    assert [f.apply_at_us for f in sent] == list(range(1_100_000, link.now_us + 60_000 + 1, PERIOD_US))


def test_without_a_stall_nothing_is_skipped() -> None:
    link = RecordingLink(now_us=1_000_000)
    s = FrameStreamer(link, Mixer(np.zeros(4)))  # type: ignore[arg-type]
    anyio.run(s.top_up)
    link.now_us += 30_000
    anyio.run(s.top_up)
    times = [f.apply_at_us for f in _frames(link)]
    assert s.frames_skipped == 0
    assert times == list(range(1_010_000, 1_090_001, PERIOD_US))


def test_a_lockstep_board_is_never_skipped_ahead() -> None:
    """In lockstep the board runs only as far as the frames reach: nothing is ever late."""
    link = RecordingLink(now_us=1_000_000, lockstep=True)
    s = FrameStreamer(link, Mixer(np.zeros(4)))  # type: ignore[arg-type]
    link.now_us = 1_500_000
    anyio.run(s.top_up)
    assert s.frames_skipped == 0 and _frames(link)[0].apply_at_us == 1_010_000


def test_the_reach_counts_the_frames_own_wire_time() -> None:
    """Over a modelled line the link's latency grows with the message: a full frame's wire time moves
    the first frame still in reach."""
    link = RecordingLink(now_us=1_000_000, us_per_byte=100.0)  # 100 us a byte: 1 ms per 10 bytes
    s = FrameStreamer(link, Mixer(np.zeros(4)))  # type: ignore[arg-type]
    nbytes = frame_wire_bytes(4, s.schema)
    link.now_us = 1_050_000
    anyio.run(s.top_up)
    reach = link.now_us + link.uplink_us + round(100.0 * nbytes) + SEND_PATH_DEFAULT_US
    first = _frames(link)[0].apply_at_us
    assert first == -(-reach // PERIOD_US) * PERIOD_US
    assert first - PERIOD_US < reach  # the one before it could not have made it
    assert s.frames_skipped == 0  # the first top-up: nothing was expected yet


def test_a_stall_after_the_first_frames_counts_what_it_skipped() -> None:
    """Once frames went out, grid frames left unsent because they could no longer arrive in time are
    counted in ``frames_skipped`` (the run's timing health reports them)."""
    link = RecordingLink(now_us=1_000_000)
    s = FrameStreamer(link, Mixer(np.zeros(4)))  # type: ignore[arg-type]
    anyio.run(s.top_up)  # frames 1.01 .. 1.06 s
    assert s.first_free_us == 1_070_000
    link.now_us = 1_095_000  # then the host stalled
    anyio.run(s.top_up)
    first = [f.apply_at_us for f in _frames(link)][6]
    assert first == 1_100_000
    assert s.frames_skipped == (first - 1_070_000) // PERIOD_US == 3


def test_a_link_slower_than_the_lookahead_still_gets_frames() -> None:
    """Uplink p99 120 ms against a 60 ms lookahead (a ``delay=`` fault; an overloaded board's late
    TIME_SYNC replies). Every top-up used to skip past its own horizon and send nothing, and the run
    ended with "the host sent no servo frame for 10 s" (seen under load 5 on this machine). Now each
    top-up sends up to one period beyond the first time still in reach, so the board's buffer never
    runs dry while the link is slow, and nothing sent is due before it can arrive."""
    link = RecordingLink(now_us=1_000_000, uplink_us=120_000)
    s = FrameStreamer(link, Mixer(np.zeros(4)))  # type: ignore[arg-type]
    assert s.lookahead_us < link.uplink_us
    for step in range(20):  # 20 top-ups, one period apart, as the realtime topper runs them
        link.now_us = 1_000_000 + step * PERIOD_US
        before = len(_frames(link))
        anyio.run(s.top_up)
        new = _frames(link)[before:]
        reach = link.now_us + link.uplink_us + SEND_PATH_DEFAULT_US
        assert new, f"top-up {step} sent nothing"
        assert all(f.apply_at_us >= reach for f in new)  # none the board would NACK LATE
        assert s.first_free_us > reach + PERIOD_US  # sent through one period beyond the reach
    times = [f.apply_at_us for f in _frames(link)]
    assert times == sorted(set(times))  # each grid time once, in order: no gaps once streaming
    assert times == list(range(times[0], times[-1] + 1, PERIOD_US))


def test_the_lead_stays_within_max_lead_however_slow_the_link_says_it_is() -> None:
    """A latency estimate of 1.5 s: frames go out up to 1.5 s + a period ahead. Of 3 s (a bogus
    estimate, or a line that cannot carry the frame rate: its backlog is part of the latency):
    nothing beyond ``max_lead_us`` (2 s), so the board's 256-frame jitter buffer and its 5 s
    ``max_future_us`` are safe; the run's silence check then ends the run, naming the latency."""
    for uplink_us, sends in ((1_500_000, True), (3_000_000, False)):
        link = RecordingLink(now_us=1_000_000, uplink_us=uplink_us)
        s = FrameStreamer(link, Mixer(np.zeros(4)))  # type: ignore[arg-type]
        anyio.run(s.top_up)
        times = [f.apply_at_us for f in _frames(link)]
        assert bool(times) is sends, (uplink_us, len(times))
        assert all(t <= link.now_us + s.max_lead_us for t in times)
        if sends:
            assert min(times) >= link.now_us + uplink_us  # none the board would NACK LATE


def test_a_cut_on_a_slow_link_is_not_before_its_flush_can_arrive() -> None:
    """A realtime cut stops the motion two periods from board now, unless its re-sent frames cannot get
    there by then (uplink 80 ms: a ``delay=80`` fault; they go out after the FLUSH's ACK, so a FLUSH,
    its ACK and a frame must make the trip): then at the first grid time they can reach, so the
    board does not NACK them LATE (a live run NACKed one 154 ms late when only the FLUSH was counted)."""
    link = RecordingLink(now_us=1_000_000, uplink_us=80_000)
    s = FrameStreamer(link, Mixer(np.zeros(4)))  # type: ignore[arg-type]
    seg = s.add(Ramp(), "ramp")
    anyio.run(s.top_up)
    anyio.run(s.cut, [seg], [0, 1], lambda q: None)
    i = next(k for k, m in enumerate(link.sent) if isinstance(m, tuple) and m[0] == "FLUSH")
    cut_us = link.sent[i][1]
    resent = [m.apply_at_us for m in link.sent[i + 1:] if isinstance(m, ServoFrame)]
    reach = link.now_us + 3 * link.uplink_us + SEND_PATH_DEFAULT_US
    # at the first unsent frame (nothing sent after it to replace) or where the re-sent frames can reach
    assert cut_us % PERIOD_US == 0 and (cut_us == s.first_free_us or cut_us >= reach)
    assert cut_us > link.now_us + 2 * PERIOD_US  # not the fast link's two periods
    assert all(t >= reach for t in resent), resent  # none the board would NACK LATE

    fast = RecordingLink(now_us=1_000_000)  # a pty's 0.3 ms: the usual two periods
    s = FrameStreamer(fast, Mixer(np.zeros(4)))  # type: ignore[arg-type]
    seg = s.add(Ramp(), "ramp")
    anyio.run(s.top_up)
    anyio.run(s.cut, [seg], [0, 1], lambda q: None)
    assert [m for m in fast.sent if isinstance(m, tuple) and m[0] == "FLUSH"][-1][1] == 1_000_000 + 2 * PERIOD_US
