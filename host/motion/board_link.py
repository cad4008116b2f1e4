"""The streamer's link (:class:`host.motion.streamer.FrameLink`) over a :class:`host.link.BoardClient`."""

from __future__ import annotations

import contextlib
import time

import anyio

from host.link import BoardClient, LinkError
from host.motion.streamer import slow_line
from host.motion.txqueue import EdfFrameQueue, SeqCallback
from protocol.messages import Flush, ServoFrame
from protocol.wiremodel import WireModel

#: One-way latency (µs) assumed before any TIME_SYNC round trip was measured.
DEFAULT_LATENCY_US = 2_000

#: :meth:`BoardFrameLink.pace` writes the next held frame once the modelled line has at most this
#: much left to send (s): the line does not idle for the host's wake-up, and a message written
#: directly waits behind at most this plus the frame being written.
PACE_SLACK_S = 0.0005

#: ... unless the held frame due first would then risk being late: once its apply time is within the
#: link's latency (line backlog included) plus this margin (µs) of the board clock, it is written at
#: once. The pacing writes one frame per wake-up, so on a loaded machine late wake-ups would add up;
#: after a stall, the frames that are due soon go out together.
PACE_MARGIN_US = 10_000


class BoardFrameLink:
    """Frames, flushes and the board clock of a :class:`BoardClient`, as the streamer needs them.

    ``wire_baud``: the baud rate the board models wire time at (its ``--baud``), or None for a
    plain pty; the client models its line at that rate from then on (``client.tx_wire``, unless it
    already does), and :meth:`latency_us` takes the line's wire time from that one model.

    Two ways to send a frame: :meth:`send_start` writes it at once, then a FLUSH of its servos (a new
    motion's first frame), and :meth:`queue_frame` (lookahead, re-sent grid) writes it at once too,
    unless :meth:`pace` runs: then it waits in :attr:`queue` (earliest apply time first,
    :mod:`host.motion.txqueue`) and is written when the modelled line (``client.tx_wire``) has
    drained, so what is written at once waits behind at most one frame. A FLUSH (:meth:`flush`,
    :meth:`send_start`) is written at once and acts on the held frames as the board's would.
    """

    def __init__(self, client: BoardClient, wire_baud: int | None = None) -> None:
        self.client = client
        if wire_baud and client.tx_wire is None:  # the host models its own line from now on
            client.tx_wire = WireModel(wire_baud)
        robot = client.robot
        #: a slow line (:func:`host.motion.streamer.slow_line`): the streamer's grid frames carry only the
        #: servos that move (``FrameStreamer.sparse``)
        self.sparse_frames = robot is not None and slow_line(robot.servo_count, wire_baud)
        #: frames held while :meth:`pace` runs
        self.queue = EdfFrameQueue()
        self._pacing = False
        self._wake: anyio.Event | None = None

    @property
    def lockstep(self) -> bool:
        return self.client.lockstep

    @property
    def tick_us(self) -> int:
        caps = self.client.caps
        return 1_000_000 // caps.control_rate_hz if caps is not None and caps.control_rate_hz else 2_000

    def board_now_us(self) -> int:
        return self.client.board_now_estimate()

    def report_period_us(self) -> int:
        """The board's report period plus a tick (µs), at the rate in force (CAPS, or the handshake's CONFIG)."""
        return self.client.report_period_us()

    def latency_us(self, nbytes: int = 0, q: float = 0.99) -> int:
        """Host -> board latency (µs) for a message of ``nbytes`` sent now, by default its p99: the ``q``
        quantile (0..1) of the TIME_SYNC requests' measured uplink beyond the line
        (``ClockSync.uplink_quantile``), plus, with
        ``wire_baud``, how long the line is still busy with bytes sent before (the host's model of it,
        ``BoardClient.tx_wire``: known now, not a p99 of past queues) and the message's own wire time
        (``WireModel.wire_s``: ``10 * nbytes / baud``, 8N1)."""
        up = self.client.clock.uplink_quantile(q)
        one_way = DEFAULT_LATENCY_US if up is None else up
        line = self.client.tx_wire
        if line is None:
            return int(one_way)
        return int(one_way + (line.busy_s(time.monotonic()) + line.wire_s(nbytes)) * 1e6)

    def send_start(self, frame: ServoFrame) -> int:
        """Write ``frame`` ahead of any held frame, then FLUSH its servos from just after its apply time
        (not awaiting the ACK: a start may not cost a round trip; the held frames are flushed at once from
        its apply time on); returns its sequence number. Both are on the wire before either is logged
        (``BoardClient.burst``).

        The frame goes first: over a line of known baud the board has it one FLUSH's wire time sooner
        (19 bytes, 1.65 ms at 115 200 baud), and the streamer plans the start for the frame's arrival
        (``FrameStreamer.start_now``). The FLUSH starts 1 µs after the frame's apply time, so it leaves
        the frame alone; a frame of the old plan due at that same time stays in the board's buffer, and
        the board applies the later-arriving frame over it for the servos both cover
        (``firmware_sim.jitter_buffer``, ``gs_jitter.c``)."""
        with self.client.burst():
            self.queue.flush(frame.apply_at_us, frame.mask)  # its orphaned callbacks go with ``frame``
            seq = self._write(frame, [])
            self.client.send(Flush(int(frame.apply_at_us) + 1, int(frame.mask)))
            return seq

    def queue_frame(self, frame: ServoFrame, on_sent: SeqCallback | None = None) -> None:
        """Send ``frame`` when the line allows: at once, unless :meth:`pace` runs (then held, earliest
        apply time first). ``on_sent`` gets its sequence number when it is written."""
        if not self._pacing:
            self._write(frame, [on_sent] if on_sent else [])
            return
        while not self.queue.push(frame, on_sent):  # full (the line cannot keep up): the head goes now
            head = self.queue.pop()
            if head is None:  # only emptied frames fill it: pop() just removed them all
                continue
            self._write(*head)
        if self._wake is not None:
            self._wake.set()

    def _write(self, frame: ServoFrame, callbacks: list[SeqCallback]) -> int:
        callbacks = callbacks + self.queue.take_orphans()
        try:
            seq = self.client.send_frame(frame)
        except BaseException:  # not written (the link is down): the next frame written confirms past it
            self.queue.adopt(callbacks)
            raise
        for cb in callbacks:
            cb(seq)
        return seq

    async def flush(self, from_us: int, mask: int) -> None:
        """FLUSH (awaiting the board's ACK); the held frames are flushed the same way at once, before the
        wait (the pacing may write them meanwhile). A FLUSH that then fails (NACK, no ACK) raises, and
        the caller (``FrameStreamer.cut``) fails with it; the held frames stay trimmed."""
        self.queue.flush(from_us, mask)
        await self.client.flush(from_us, mask)

    @property
    def paced(self) -> bool:
        """True while :meth:`pace` runs (frames from :meth:`queue_frame` are held)."""
        return self._pacing

    async def pace(self) -> None:
        """Write held frames one at a time as the modelled line drains, until cancelled.

        Runs only over a realtime link whose line the host models (``client.tx_wire``, a board with
        ``--baud``); otherwise it returns at once and frames are written when queued. A lockstep
        board's time does not run with the wall clock, so its frames are never held. It measures the line
        on ``time.monotonic()`` and sleeps on the event loop's clock, so it needs a real-time loop (under
        Trio's autojumping ``MockClock`` it would spin). On the way out
        (cancelled, or the link failed) the frames still held are written as an unpaced link would
        have written them. Raises what the link raises (:class:`host.link.LinkDown`).
        """
        line = self.client.tx_wire
        if line is None or self.client.lockstep or self._pacing:
            return
        self._pacing = True
        self._wake = anyio.Event()
        try:
            while True:
                due = self.queue.next_apply_at()
                if due is None:
                    await self._wake.wait()
                    self._wake = anyio.Event()
                    continue
                busy = line.busy_s(time.monotonic())
                spare_s = (due - self.board_now_us() - self.latency_us(0) - PACE_MARGIN_US) * 1e-6
                if busy > PACE_SLACK_S and spare_s > 0:
                    await anyio.sleep(min(busy - PACE_SLACK_S, spare_s))
                    continue
                item = self.queue.pop()
                if item is not None:
                    self._write(*item)
        finally:
            self._pacing = False
            self._wake = None
            for frame, callbacks in self.queue.drain():
                with contextlib.suppress(LinkError):
                    self._write(frame, callbacks)
