"""Stream mixed frames to the board a little ahead of its clock; confirm them from telemetry.

The streamer owns the frame grid: every ``period_us`` of board time there is
one full-body SERVO_FRAME, sent while it is still at most ``lookahead_us``
ahead of the board (on a realtime link slower than that, as far ahead as the link's latency
needs, up to ``max_lead_us``: :meth:`FrameStreamer.top_up`). It tops up whenever telemetry arrives (and, on a realtime
board, on its own every period). In lockstep the board only runs as far as the
frames reach, so topping up on telemetry is what moves board time forward, and
the host can never fall behind it.

A segment counts as started (ended) once telemetry reports that the frame it
first (last) appeared in was applied: ``last_applied_seq`` has passed that
frame's sequence number and the board clock has reached its apply time. Those
board times are what the run's timeline records.

:meth:`FrameStreamer.start_now` starts a motion on a realtime board as soon as the link allows
(token to servo within a few ms): its first frame is due at :meth:`FrameStreamer.start_due_us`
(board now + a quick uplink and send path, rounded up to the control tick grid: the board applies a
frame that arrives after its due time at its next tick, so a start is not planned for the slowest
arrival) instead of at the first unsent
frame, and the frames already sent for its servos from that time on (the hold, or what the
segment it overrides planned) are replaced: the first frame, then a FLUSH of those servos from just
after its time, then the servos' frames re-sent for the part of the grid already sent.
Later frames keep the full lookahead. The re-sent frames, and every lookahead frame, go through
:meth:`FrameLink.queue_frame`: over a slow line whose host paces it they are held and written
earliest apply time first (:mod:`host.motion.txqueue`), so the next motion's first frame and FLUSH
(written at once) wait behind at most one frame on the wire. On a lockstep board nothing of the grid has been simulated
beyond the first unsent frame's predecessor, so that frame is the soonest.

:meth:`FrameStreamer.fail` records that the board will not apply the frames (it raised ESTOP or
WATCHDOG_FAULT, or NACKed frames ESTOPPED / FAULT_LATCHED): a refused frame is never confirmed
by telemetry, so every segment waiter (:meth:`wait_started`, :meth:`wait_ended`) would wait for
ever. Instead they raise the failure at once, now and until :meth:`clear_failure`.

:meth:`FrameStreamer.cut` implements reset and interruption: it FLUSHes the
affected servos' buffered frames from a cut time on, releases their segments
there, starts the replacement motion (a smooth return or a stop) at the cut
and re-sends the affected servos' frames for the part of the grid already sent.
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import math
import time
import weakref
from collections import deque
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import anyio
import numpy as np

from host.motion.mixer import MixedFrame, Mixer, MotionLike, Segment
from host.motion.stalls import STALLS, maybe_stall
from protocol.codec import WireSchema, schema_for
from protocol.framing import encode_frame
from protocol.messages import Flush, ServoFrame, Telemetry
from protocol.wiremodel import BITS_PER_BYTE


#: The host's own send path: from planning a start (:meth:`FrameStreamer.start_due_us`) to the moment its
#: FLUSH and first frame are handed to the link (adding the segment, sampling the mix, building the frame;
#: encoding and the write are in the TIME_SYNC uplink, measured from its own write). Measured on every
#: realtime :meth:`FrameStreamer.start_now` (a window of the last ``SEND_PATH_WINDOW``; a sure estimate,
#: :meth:`FrameStreamer.soonest_us`, takes its ``SEND_PATH_QUANTILE``); this default before the first:
#: 0.24 ms p50, 0.45 ms max on a quiet 2-core machine (``bench/bench_latency.py``, n = 49).
SEND_PATH_DEFAULT_US = 400
SEND_PATH_WINDOW = 32
SEND_PATH_QUANTILE = 0.9

#: The quantile of the measured uplink and of the send path a start's first message is planned for
#: (:meth:`FrameStreamer.start_due_us`). The board applies a SERVO_FRAME that arrives after its due time
#: (up to its ``max_late_us``, 20 ms; later ones it refuses as LATE) at its first tick after the arrival,
#: anchored at its due time: the earliest any due time could give. Planned for the sure arrival (the
#: uplink p99 and the send path's 0.9 quantile), a start that arrived sooner waited at the board for
#: it. Peripheral commands start at the same time; the board takes those at any lateness, backdated.
#: Measured with ``bench/bench_latency.py``: an interleaved A/B moved the motion p50 3.4 -> 2.5 ms (n = 34
#: each, nearly quiet), but a quiet ``--repeat 4`` (n = 136) found p50 3.7, p99 6.0 ms, where the old plan
#: was: what a start waits for at the board is mostly the round-up to the 2 ms tick.
START_QUANTILE = 0.1

#: ... but never planned more than this (µs) before the sure arrival (:meth:`FrameStreamer.soonest_us`):
#: over a link whose delay jitters by more than the board's ``max_late_us`` (a ``delay=80±20`` fault)
#: a quick-arrival plan would be refused as LATE for every slow arrival. Half the board's ``max_late_us``
#: (20 ms, the protocol's SERVO_FRAME window): a start that arrives by the measured p99 is at most this
#: late, and arrivals up to 10 ms beyond that p99 are still taken. It was one tick (2 ms) until
#: 2026-12-04, which made a window whose p99 is one slow sample (a board's first second: 8-9 TIME_SYNC
#: samples, their p99 about their largest; a loaded machine's stalls) plan every start up to that sample
#: late: ``bench/bench_latency.py --baud 115200 --repeat 2`` (n = 68, CPU steal 6.4 %) had its 5 slowest
#: motion starts (16-21 ms) in a task's first second, planned ~12 ms after their quick arrival. A start
#: that arrives after its due time costs nothing beyond its lateness: the board applies it at its first
#: tick after the arrival.
START_SLACK_US = 10_000


class FrameLink(Protocol):
    """What the streamer needs from the link."""

    @property
    def lockstep(self) -> bool: ...

    def board_now_us(self) -> int: ...

    def send_start(self, frame: ServoFrame) -> int:
        """Write ``frame`` at once (nothing held may delay it), then FLUSH its servos from just after its
        apply time (``apply_at_us + 1``) without waiting for the board's ACK (a start may not cost a round
        trip); its sequence number (see :mod:`host.motion.txqueue`)."""
        ...

    def queue_frame(self, frame: ServoFrame, on_sent: Callable[[int], None] | None = None) -> None:
        """Send ``frame`` when the line allows (at once, or held earliest apply time first over a paced
        slow line: :class:`host.motion.board_link.BoardFrameLink`); ``on_sent`` gets its sequence number."""
        ...

    async def flush(self, from_us: int, mask: int) -> None: ...

    def latency_us(self, nbytes: int, q: float = 0.99) -> int:
        """How long after it is sent a message of ``nbytes`` wire bytes is on the board (µs): its ``q``
        quantile (0..1; by default the p99: surely there)."""
        ...

    @property
    def tick_us(self) -> int:
        """The board's control period (µs)."""
        ...


#: Wire bytes of a FLUSH and of a SERVO_FRAME for ``n`` servos (framing and COBS overhead included),
#: from :func:`protocol.framing.encode_frame`, in the wire schema of a robot of up to 16 servos.
FLUSH_WIRE_BYTES = len(encode_frame(Flush(0, 0xFFF), 0))


def frame_wire_bytes(n_servos: int, schema: WireSchema | None = None) -> int:
    """Wire bytes of a SERVO_FRAME for ``n_servos`` of a robot whose wire schema is ``schema``
    (default: the schema of a robot of ``n_servos`` servos)."""
    schema = schema or schema_for(max(1, n_servos))
    return len(encode_frame(ServoFrame(0, (1 << n_servos) - 1, (0.0,) * n_servos), 0, schema))


#: Wall seconds the shielded top-up that resumes a held lockstep board may take (see :meth:`FrameStreamer.hold`).
RESUME_TIMEOUT_S = 8.0

#: How far ahead of the board the grid is sent (µs) when the link is quick (:class:`FrameStreamer`)
LOOKAHEAD_US = 60_000
#: The frame grid's period (µs) when the line is fast enough: 100 frames/s, five control ticks per frame.
GRID_PERIOD_US = 10_000
#: The share of a modelled line's time the frame grid may fill (:func:`grid_period_us`); the rest carries
#: a motion start's first frame and FLUSH, re-sent frames, requests, heartbeats and TIME_SYNCs.
GRID_LINE_SHARE = 0.5
#: ... on a slow line (:func:`slow_line`): there the handshake raises the board's watchdog past the grid,
#: so no heartbeat goes out while the grid streams, and the grid's frames carry only the servos that move
#: (:class:`FrameStreamer` ``sparse``): full-body frames may fill this share, and usually fill less.
SLOW_GRID_LINE_SHARE = 0.8
#: the board's default watchdog (µs; both boards) and the watchdog a slow line's handshake asks for, in grid
#: periods (:mod:`host.motion.line_cadence`)
BOARD_WATCHDOG_US = 200_000
WATCHDOG_GRID_PERIODS = 3


def _grid_steps(frame_s: float, share: float) -> int:
    return max(1, math.ceil(frame_s / share / (GRID_PERIOD_US * 1e-6) - 1e-9))


def slow_line(n_servos: int, baud: int | None, schema: WireSchema | None = None) -> bool:
    """Whether a line of ``baud`` is slow for a robot of ``n_servos``: its grid at :data:`GRID_LINE_SHARE`
    would be longer than a third of the board's default watchdog (CoCo: below ~11 000 baud), so the
    gaps between frames tripped it; the handshake then raises the watchdog (:mod:`host.motion.line_cadence`)."""
    if not baud:
        return False
    frame_s = frame_wire_bytes(n_servos, schema) * BITS_PER_BYTE / baud
    return WATCHDOG_GRID_PERIODS * _grid_steps(frame_s, GRID_LINE_SHARE) * GRID_PERIOD_US > BOARD_WATCHDOG_US


def grid_period_us(n_servos: int, baud: int | None, schema: WireSchema | None = None) -> int:
    """The frame grid's period (µs) over a line of ``baud`` bit/s (8N1): the smallest multiple of
    :data:`GRID_PERIOD_US` whose full-body SERVO_FRAME (:func:`frame_wire_bytes`) fills at most
    :data:`GRID_LINE_SHARE` of it (:data:`SLOW_GRID_LINE_SHARE` on a :func:`slow_line`);
    :data:`GRID_PERIOD_US` for None (a line the host does not model).

    12 servos (39 wire bytes): 10 ms down to 78 000 baud, 20 ms at 57 600, 60 ms at 9 600, 210 ms at
    2 400. A grid the line cannot carry (100 frames/s at 2 400 baud needs 39 000 bit/s) queued frames
    until the lead limit stopped the run ("the host sent no servo frame for 10 s"); a slower grid
    moves the servos in coarser straight segments (the board interpolates between frames): at 2 400
    baud with a share of 0.5 (330 ms) CoCo's two strides of Task 26 (a 0.7-s gait cycle) moved the base
    1.8 cm instead of 8.2; at 210 ms 7.4 cm."""
    if not baud:
        return GRID_PERIOD_US
    frame_s = frame_wire_bytes(n_servos, schema) * BITS_PER_BYTE / baud
    share = SLOW_GRID_LINE_SHARE if slow_line(n_servos, baud, schema) else GRID_LINE_SHARE
    return _grid_steps(frame_s, share) * GRID_PERIOD_US


#: a sparse grid frame (:meth:`FrameStreamer._sparse_frame`) leaves out a servo whose target moves less than
#: this (rad) to and from the frame: below the wire's resolution (SERVO_FRAME targets are in 1e-4 rad)
SPARSE_EPS_RAD = 1e-5


def flush_wire_bytes(schema: WireSchema | None = None) -> int:
    """Wire bytes of a FLUSH in ``schema`` (default: the u16 schema)."""
    return len(encode_frame(Flush(0, 1), 0, schema))


def mask_of(servos: Sequence[int]) -> int:
    m = 0
    for i in servos:
        m |= 1 << int(i)
    return m


@dataclass
class _Sent:
    seq: int | None  # None while the link holds the frame unwritten (see FrameLink.queue_frame)
    frame: MixedFrame

    def written(self, seq: int) -> None:
        self.seq = seq


@dataclass
class SegmentTimes:
    """Board-confirmed times of a segment (seconds), with events to wait on."""

    start: float | None = None
    end: float | None = None
    started: anyio.Event = field(default_factory=anyio.Event)
    ended: anyio.Event = field(default_factory=anyio.Event)


class FrameStreamer:
    """Keeps the board fed with frames from a :class:`Mixer`."""

    def __init__(self, link: FrameLink, mixer: Mixer, *, period_us: int = GRID_PERIOD_US, lookahead_us: int = LOOKAHEAD_US,
                 start_us: int | None = None, history: int = 720_000, max_lead_us: int = 2_000_000,
                 sparse: bool = False) -> None:
        self.link = link
        #: grid frames carry only the servos that move (:meth:`_send`): a slow line's rule, which the caller
        #: passes from :attr:`host.motion.board_link.BoardFrameLink.sparse_frames`
        self.sparse = sparse
        self._prev_targets: np.ndarray | None = None  # the last grid frame's targets (sparse)
        self.mixer = mixer
        #: the robot's wire schema (the mask's width): what a FLUSH and a frame cost on the wire
        self.schema = schema_for(max(1, mixer.n_servos))
        self._flush_bytes = flush_wire_bytes(self.schema)
        self._frame_bytes = frame_wire_bytes(max(1, mixer.n_servos), self.schema)  # a full-body grid frame
        self.period_us = period_us
        self.lookahead_us = lookahead_us
        #: realtime: the farthest ahead of board now a top-up sends, however slow the link (top_up)
        self.max_lead_us = max_lead_us
        now = link.board_now_us() if start_us is None else start_us
        self.next_us = self._grid(now + period_us)
        self._in_flight: deque[_Sent] = deque()
        self._times: weakref.WeakKeyDictionary[Segment, SegmentTimes] = weakref.WeakKeyDictionary()
        self._last_telemetry: Telemetry | None = None
        self._lock = anyio.Lock()
        self.frames_sent = 0
        self.frames_skipped = 0  # grid frames left unsent: they could no longer arrive in time (_skip_late)
        self._holds = 0
        self._time_waiters: list[tuple[int, int, anyio.Event]] = []
        self._waiter_ids = itertools.count()
        self.history: deque[tuple[int, np.ndarray]] = deque(maxlen=history)  # (t_us, targets) sent
        self.failure: Exception | None = None  # why the board will not apply our frames (see fail())
        self._last_failure: Exception | None = None
        self._send_path_s: deque[float] = deque(maxlen=SEND_PATH_WINDOW)  # measured by start_now (s)
        self._busy = 0  # control work under way that a lockstep top-up waits for (busy())
        self._idle = anyio.Event()  # set (and replaced) when the last hold or busy section ends

    def grid(self, t_us: int) -> int:
        """The first frame time on the grid at or after ``t_us``."""
        p = self.period_us
        return -(-int(t_us) // p) * p

    _grid = grid

    # -- planning ----------------------------------------------------------------------------
    @property
    def first_free_us(self) -> int:
        """Board time of the next frame not yet sent: where a new motion can start."""
        return self.next_us

    def planned_targets(self, t_us: int | None = None) -> np.ndarray:
        """Targets the mix gives at ``t_us`` (default: the first unsent frame)."""
        return self.mixer.sample_servo_targets(self.next_us if t_us is None else t_us)

    def add(self, motion: MotionLike, label: str = "", start_us: int | None = None) -> Segment:
        """Start ``motion`` at the first unsent frame (or later)."""
        start = self.next_us if start_us is None else max(self._grid(start_us), self.next_us)
        seg = self.mixer.add(motion, start, label)
        self._times[seg] = SegmentTimes()
        return seg

    def times(self, seg: Segment) -> SegmentTimes:
        return self._times.setdefault(seg, SegmentTimes())

    async def wait_started(self, seg: Segment) -> float:
        """Board time (s) the segment's first frame was applied; raises :attr:`failure` if the board refuses frames."""
        t = self.times(seg)
        if not t.started.is_set():
            self._raise_failure()
            await t.started.wait()
            await self._resumed("wait_started")
        if t.start is None:
            raise self._last_failure or RuntimeError("segment woken without a start")
        return t.start

    async def wait_ended(self, seg: Segment) -> float:
        """Board time (s) the segment's last frame was applied; raises :attr:`failure` if the board refuses frames."""
        t = self.times(seg)
        if not t.ended.is_set():
            self._raise_failure()
            await t.ended.wait()
            await self._resumed("wait_ended")
        if t.end is None:
            raise self._last_failure or RuntimeError("segment woken without an end")
        return t.end

    def _raise_failure(self) -> None:
        if self.failure is not None:
            raise self.failure

    def fail(self, error: Exception) -> None:
        """The board refuses our frames (``error`` says why): wake every segment waiter, which raises
        ``error``, and make new waits raise it too until :meth:`clear_failure`. The first failure is kept."""
        if self.failure is not None:
            return
        self.failure = self._last_failure = error
        for st in list(self._times.values()):
            if st.start is None:
                st.started.set()
            if st.end is None:
                st.ended.set()
        waiters, self._time_waiters = self._time_waiters, []
        for _, _, event in waiters:
            event.set()

    def clear_failure(self) -> None:
        """Forget a failure (after the board's fault was cleared); segments woken by it stay failed."""
        self.failure = None

    def send_path_us(self, q: float = SEND_PATH_QUANTILE) -> int:
        """The host's own send path (µs): the ``q`` quantile (0..1, by default :data:`SEND_PATH_QUANTILE`)
        of the last :data:`SEND_PATH_WINDOW` realtime starts, from planning the start to handing its FLUSH
        and first frame to the link; :data:`SEND_PATH_DEFAULT_US` before the first."""
        window = sorted(self._send_path_s)
        if not window:
            return SEND_PATH_DEFAULT_US
        return round(window[min(len(window) - 1, int(q * len(window)))] * 1e6)

    def soonest_us(self, nbytes: int = 0) -> int:
        """Earliest board time (µs) a message of ``nbytes`` sent now can be due at without being late.

        Realtime: the board clock estimate + the link's measured latency p99 (wire time of
        ``nbytes`` included) + the host's own send path (:meth:`send_path_us`: the uplink is measured
        from the moment a TIME_SYNC is written, a start still has to be sampled and built), rounded
        up to the board's control-tick grid (ticks run at whole multiples of ``tick_us``), so the
        message is due exactly at the first tick it can reach in time: a margin of up to one tick
        beyond that, and no extra tick of waiting for the board to apply it. Never later than the
        first unsent frame. Lockstep: the first unsent frame.
        """
        if self.link.lockstep:
            return self.next_us
        return self._on_grid(self.link.board_now_us() + self.link.latency_us(nbytes) + self.send_path_us())

    def start_due_us(self, nbytes: int = 0, then_nbytes: int = 0) -> int:
        """Board time (µs) a start's first message of ``nbytes`` sent now is due at: as :meth:`soonest_us`,
        but for a quick arrival (the :data:`START_QUANTILE` of the measured uplink and of the send path)
        rather than a sure one, and never more than :data:`START_SLACK_US` before the sure one. The
        board applies a frame that arrives after its due time at its first tick after the arrival, so
        the start takes effect as soon as the message is there; one that arrives sooner waits until the
        tick at or after its due time. With ``then_nbytes`` > 0, a second message of that size written
        right behind the first (a start's FLUSH, :meth:`start_now`) must also be there by the tick after
        the due time. Lockstep: the first unsent frame."""
        if self.link.lockstep:
            return self.next_us
        now = self.link.board_now_us()
        path_quick = self.send_path_us(START_QUANTILE)
        path_sure = self.send_path_us()

        def due(n: int) -> int:
            quick = now + self.link.latency_us(n, START_QUANTILE) + path_quick
            sure = now + self.link.latency_us(n) + path_sure
            return max(quick, sure - START_SLACK_US)

        t = due(nbytes)
        if then_nbytes > 0:
            t = max(t, due(nbytes + then_nbytes) - self.link.tick_us)
        return self._on_grid(t)

    def _on_grid(self, t: int) -> int:
        """Board time ``t`` (µs) rounded up to the control-tick grid, and never after the first unsent frame."""
        tick = self.link.tick_us
        return min(-(-t // tick) * tick, self.next_us)

    async def start_now(self, motion: MotionLike, label: str = "") -> Segment:
        """Start ``motion`` at :meth:`start_due_us`, replacing the frames already sent for its servos."""
        async with self._lock:
            began = time.perf_counter()
            servos = sorted(int(i) for i in motion.servos)
            mask = mask_of(servos)
            # the first frame goes on the wire before its FLUSH (FrameLink.send_start): planned for the
            # frame's arrival, and for the FLUSH's by the tick after it (when the old plan would go on)
            t0 = self.start_due_us(frame_wire_bytes(len(servos), self.schema), self._flush_bytes)
            if t0 >= self.next_us:
                seg = self.mixer.add(motion, self.next_us, label)
                self._times[seg] = SegmentTimes()
                return seg
            seg = self.mixer.add(motion, t0, label)
            self._times[seg] = SegmentTimes()
            idx = np.asarray(servos, dtype=int)
            first = self.mixer.sample_servo_targets(t0)
            frame = ServoFrame(t0, mask, tuple(float(x) for x in first[idx]))
            # the send path ends where the write begins: the uplink measured by TIME_SYNC starts there too
            self._send_path_s.append(time.perf_counter() - began)
            seq = self.link.send_start(frame)  # then FLUSH: nothing buffered for these servos survives after t0
            seg.first_frame_us = t0
            self._in_flight.append(_Sent(seq, MixedFrame(t0, first, (seg,), ())))
            for t in range(self.grid(t0 + 1), self.next_us, self.period_us):
                q = self.mixer.sample_servo_targets(t)[idx]
                self.link.queue_frame(ServoFrame(t, mask, tuple(float(x) for x in q)))
            return seg

    # -- sending -------------------------------------------------------------------------------
    @contextlib.asynccontextmanager
    async def hold(self) -> AsyncIterator[None]:
        """Keep a lockstep board where it is while the host waits for wall-clock input (a real LLM's next
        chunk, an MCP server's answer).

        A lockstep board runs only as far as frames reach, so not topping up
        freezes board time; on a realtime board holding would starve it, so it is
        a no-op there. The telemetry driver goes on handling reports meanwhile (it only sends no
        frames), and the hold's end tops up from the link's board clock estimate: the board runs one
        lookahead further each time the input comes. (What the input is and when it comes are not the
        host's to decide, so neither is the board time it meets; host work that takes wall time but has
        no such input, speech synthesis, is :meth:`busy` instead: the board then waits for it at a
        report, and a run stays a function of its input.)
        """
        if not self.link.lockstep:
            yield
            return
        self._holds += 1
        try:
            yield
        finally:
            self._holds -= 1
            if self._holds == 0:  # resume the board however the held work ended
                # bounded: this runs while the caller may be cancelled, and the frame lock may be held
                # by a cut waiting for an ACK; a resume that cannot happen must not hang the caller
                with anyio.CancelScope(shield=True), anyio.move_on_after(RESUME_TIMEOUT_S):
                    await self.top_up()

    @property
    def held(self) -> bool:
        """True while a lockstep board is held still (see :meth:`hold`)."""
        return self._holds > 0

    @contextlib.asynccontextmanager
    async def busy(self) -> AsyncIterator[None]:
        """Mark control work that reacts to a report and waits on something other than board time (a
        thread, a reply from the board, wall time): in lockstep the telemetry driver tops up only once no
        such work is under way (:func:`host.motion.driver.react`), so what the work sends, and what it
        leads to, precedes the frames that move board time on. The work must not wait for board time
        itself (it would wait for ever); a lockstep board answers requests while it waits for frames.
        A no-op on a realtime board (nothing waits for it there)."""
        if not self.link.lockstep:
            yield
            return
        self._busy += 1
        try:
            yield
        finally:
            self._busy -= 1
            self._maybe_idle()

    @property
    def busy_count(self) -> int:
        """How many :meth:`busy` sections are under way."""
        return self._busy

    @property
    def reacting(self) -> bool:
        """True while a :meth:`busy` section is under way: a lockstep top-up waits for it."""
        return self._busy > 0

    def _maybe_idle(self) -> None:
        if not self.reacting:
            self._idle.set()
            self._idle = anyio.Event()

    async def wait_not_busy(self) -> None:
        """Return once no :meth:`busy` section is under way."""
        while self.reacting:
            await self._idle.wait()

    async def _resumed(self, point: str) -> None:
        """A task woken by a report resumes: the stall-injection point of :mod:`host.motion.stalls`."""
        if STALLS is not None:
            async with self.busy():
                await maybe_stall(point)

    async def top_up(self, board_now_us: int | None = None) -> None:
        """Send frames up to the board clock (or ``board_now_us``) plus the lookahead.

        Realtime, on a link slower than the lookahead (uplink p99 + send path > ``lookahead_us``: a
        ``delay=`` fault, an overloaded board whose TIME_SYNC replies came late), the horizon is the
        first grid time a frame sent now can reach (:meth:`_skip_late`) plus one period: frames keep
        going out, each in time by the link's own p99, instead of every top-up skipping past its own
        horizon and sending nothing (the run then ended with "the host sent no servo frame for 10 s").
        Lockstep: the frames reach at least one grid period plus one report period past the report's board
        time, so the board runs on to its next report by itself. On a slow line the grid (330 ms at 2 400
        baud) and the report period (1 s once the handshake lowered the rate: :mod:`host.motion.line_cadence`)
        are longer than the lookahead; the board stopped at the last frame short of its next report, and
        only the wall-clock ADVANCE nudges of the waits moved it on (609 of them in a 19-s run).
                Never more than ``max_lead_us`` ahead of board now: a bogus latency estimate must not fill the
        board's jitter buffer (256 frames, 2.56 s at 100 Hz) nor reach past its ``max_future_us`` (5 s),
        and a line that cannot carry the frame rate (its backlog is part of the latency) must not
        queue without bound; beyond that lead nothing is sent, and the run's silence check ends it
        naming the latency.
        """
        if self._holds:
            return
        async with self._lock:
            now = self.link.board_now_us() if board_now_us is None else board_now_us
            horizon = now + self.lookahead_us
            if self.link.lockstep:
                horizon = max(horizon, now + self.period_us + self._report_period_us())
            if not self.link.lockstep:
                reach = self._skip_late(now)
                horizon = max(horizon, min(reach + self.period_us, now + self.max_lead_us))
            while self.next_us <= horizon:
                self._send(self.mixer.frame(self.next_us))
                self.next_us += self.period_us

    def _report_period_us(self) -> int:
        """The board's report period (µs) when the link knows it (``report_period_us()``, optional on a
        :class:`FrameLink`: :class:`host.motion.board_link.BoardFrameLink` has it), else 0."""
        period = getattr(self.link, "report_period_us", None)
        return int(period()) if callable(period) else 0

    def _skip_late(self, now_us: int) -> int:
        """Realtime: move the first unsent frame past the grid times a frame sent now would miss, by the
        link's own estimate (board now + :meth:`FrameLink.latency_us` of a full frame, i.e. the uplink
        p99, the line's backlog and the frame's wire time, + :meth:`send_path_us`).

        Those frames would reach the board after their due time and be NACKed LATE. This happens after
        a stall of the host longer than the lookahead, or when the first top-up comes over a period
        after the streamer was made (a slow session start, a loaded machine). The mix is sampled at
        the first time still in reach: a segment that began or ended in the gap is started (ended) by
        that frame, and the board moves there from where it was. Counted in ``frames_skipped`` once a frame
        was sent: before the first, the grid only starts later (the board expected nothing yet; a session
        that waits for its recording's scene before it streams skipped ~20 "frames" that way). (On a
        paced line, frames already held with earlier apply times still go first:
        :mod:`host.motion.txqueue`.) Returns that reach (board µs).
        """
        reach = now_us + self.link.latency_us(self._frame_bytes) + self.send_path_us()
        if self.next_us < reach:
            first = self._grid(reach)
            if self.frames_sent:
                self.frames_skipped += (first - self.next_us) // self.period_us
            self.next_us = first
        return reach

    def _send(self, mixed: MixedFrame) -> None:
        n = self.mixer.n_servos
        sent = _Sent(None, mixed) if mixed.started or mixed.ended else None
        if self.sparse:
            frame = self._sparse_frame(mixed)
        else:
            frame = ServoFrame(mixed.t_us, (1 << n) - 1, tuple(float(x) for x in mixed.targets))
        self.link.queue_frame(frame, sent.written if sent is not None else None)  # LinkDown: nothing recorded
        if sent is not None:
            self._in_flight.append(sent)
        self.frames_sent += 1
        self.history.append((mixed.t_us, mixed.targets))

    def _sparse_frame(self, mixed: MixedFrame) -> ServoFrame:
        """The grid frame at ``mixed.t_us`` with only the servos that move: those whose target differs (by
        more than :data:`SPARSE_EPS_RAD`) from the previous grid frame's or from the next grid time's (so a
        servo about to move has its keyframe one period before, where its straight segment starts). The
        first frame carries every servo; a frame in which nothing moves carries servo 0 alone (a frame
        needs one servo; a lockstep board runs only as far as frames reach, and every frame feeds the
        watchdog). A held servo left out keeps its last target on the board (docs/wire-protocol.md)."""
        q = mixed.targets
        prev = self._prev_targets
        self._prev_targets = q
        if prev is None:
            moving = np.ones(len(q), dtype=bool)
        else:
            nxt = self.mixer.sample_servo_targets(mixed.t_us + self.period_us)
            moving = (np.abs(q - prev) > SPARSE_EPS_RAD) | (np.abs(nxt - q) > SPARSE_EPS_RAD)
            if not moving.any():
                moving[0] = True
        idx = np.flatnonzero(moving)
        return ServoFrame(mixed.t_us, mask_of(idx.tolist()), tuple(float(x) for x in q[idx]))

    async def cut(self, segments: Sequence[Segment], servos: Sequence[int],
                  make_replacement: Callable[[np.ndarray], MotionLike | None], label: str = "",
                  margin_us: int | None = None) -> Segment | None:
        """Stop ``segments`` on ``servos`` as soon as the link allows; start a replacement there.

        ``make_replacement`` gets all servo targets at the cut and returns the
        motion to run from there (a smooth return or stop), or None to hold.
        """
        async with self._lock:
            if self.link.lockstep:
                # A lockstep board handles the FLUSH only after simulating every frame already
                # sent, so the earliest cut that is not retroactive is the first unsent frame.
                cut_us = self.next_us
            else:
                margin = 2 * self.period_us if margin_us is None else margin_us
                now = self.link.board_now_us()
                # the frames re-sent from the cut go out after the FLUSH's ACK: not before the FLUSH, its
                # ACK and then a frame can make the trip (the downlink taken as long as the uplink's
                # p99; a link slower than the margin: delay= faults. On a pty this is ~1 ms: the margin)
                up = self.link.latency_us(self._flush_bytes)
                reach = now + 2 * up + self.link.latency_us(self._frame_bytes) + self.send_path_us()
                cut_us = min(self._grid(max(now + margin, reach)), self.next_us)
            q_cut = self.mixer.sample_servo_targets(cut_us)
            for seg in segments:
                self.mixer.release(seg, cut_us)
            replacement = make_replacement(q_cut)
            new = None
            if replacement is not None:
                new = self.mixer.add(replacement, cut_us, label)
                self._times[new] = SegmentTimes()
            mask = mask_of(servos)
            await self.link.flush(cut_us, mask)  # nothing buffered for these servos survives the cut
            if cut_us < self.next_us:
                idx = np.asarray(sorted(servos), dtype=int)
                for t in range(cut_us, self.next_us, self.period_us):
                    q = self.mixer.sample_servo_targets(t)[idx]
                    self.link.queue_frame(ServoFrame(t, mask, tuple(float(x) for x in q)))
            return new

    # -- board time ----------------------------------------------------------------------------
    @property
    def board_time_us(self) -> int:
        """Board time of the last telemetry report handled (None before the first: the link's)."""
        return self._last_telemetry.board_time_us if self._last_telemetry else self.link.board_now_us()

    def board_now_us(self) -> int:
        """The board clock as the host should see it: in lockstep the last report handled (so
        everything waiting on board time wakes in report order); in realtime the link's estimate."""
        return self.board_time_us if self.link.lockstep else self.link.board_now_us()

    async def wait_board_time(self, t_us: int) -> None:
        """Return once a handled telemetry report shows board time ``t_us`` or later; raises
        :attr:`failure` when the board refuses frames (a lockstep board would not get there)."""
        if self._last_telemetry is not None and self._last_telemetry.board_time_us >= t_us:
            return
        self._raise_failure()
        event = anyio.Event()
        heapq.heappush(self._time_waiters, (int(t_us), next(self._waiter_ids), event))
        await event.wait()
        await self._resumed("wait_board_time")
        if self._last_telemetry is None or self._last_telemetry.board_time_us < t_us:
            raise self._last_failure or RuntimeError("board-time waiter woken early")

    # -- confirming ----------------------------------------------------------------------------
    def on_telemetry(self, tel: Telemetry) -> None:
        """Confirm frames the board reports applied; wake board-time waiters that are due."""
        self._last_telemetry = tel
        while self._time_waiters and self._time_waiters[0][0] <= tel.board_time_us:
            heapq.heappop(self._time_waiters)[2].set()
        while self._in_flight:
            sent = self._in_flight[0]
            if sent.seq is None:  # still held by the link: not on the board yet
                break
            applied = ((tel.last_applied_seq - sent.seq) & 0xFFFF) < 0x8000
            if not (applied and tel.board_time_us >= sent.frame.t_us):
                break
            self._in_flight.popleft()
            t_s = sent.frame.t_us * 1e-6
            for seg in sent.frame.started:
                st = self.times(seg)
                st.start = t_s
                st.started.set()
            for seg in sent.frame.ended:
                st = self.times(seg)
                if st.start is None:
                    st.start = t_s
                    st.started.set()
                st.end = t_s
                st.ended.set()
