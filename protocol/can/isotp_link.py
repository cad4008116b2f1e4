"""One ISO-TP (ISO 15765-2) link over CAN frames, driven by polling (can-isotp's TransportLayerLogic).

Shared by both ends: the host drives it from its asyncio loop, the board from its select loop, and
the fuzzer and the log decoder in listen mode. It does no I/O and starts no thread: frames for the
link are pushed in with :meth:`IsoTpLink.feed`, frames it emits go to ``send``,
and :meth:`poll` advances it (call it whenever something arrived and every few ms while
:attr:`busy`). Block size 0 and STmin 0: one flow control per message, no pacing; frames padded to 8 (FD: 64) bytes.

Timers (N_Bs: a flow control after a First Frame; N_Cr: the next consecutive frame) are can-isotp's
logic on this link's clock (``clock``, ns, ``time.perf_counter_ns`` unless given), and a received
frame is judged at the time it *arrived*, not at the time the loop got round to it: ``feed`` stamps
it (from ``CanFrame.timestamp``, the driver's arrival time, when there is one), and while
:meth:`poll` works through the frames that were waiting, "now" for a timeout is the stamp of the
frame in hand. A timer starts when its frame goes out (now). So a loop that stalls (a garbage
collection, a long lockstep batch, a starved process) with the peer's frames already in its socket
loses no transfer; only frames that really came late time out (ISO 15765-2 clause 9.8.2 measures
N_Bs and N_Cr to a frame's reception). can-isotp reads ``time.perf_counter_ns`` inside its private
``Timer``; :class:`_StampedLayer` replaces the two timers it restarts (``_start_rx_fc_timer``,
``_start_rx_cf_timer``, can-isotp 2.0) with ones on this clock, and a test checks they are in use.

**Lockstep** (``board_clock``, ns of board time; :meth:`IsoTpLink.use_board_clock`): N_Bs and N_Cr
count board time instead, with ISO 15765-2's own 1 000 ms of wall time (``ISOTP_BACKSTOP_MS``) as
the backstop for a peer that went away. A lockstep board's clock runs only as far as the host's
frames and ADVANCEs let it (never past a frame the host has not sent), and the host reads the
board's frames in order, answering a First Frame before it learns of later board time. So a peer
that is slow in wall time (a collection, a starved process) times out no transfer on the board's
clock, and a lockstep run's bytes do not depend on how busy the host is. The board uses its own
time; the host the latest board time reported. The C firmware's ``gs_isotp.c`` does the same.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable

import isotp
from isotp.tools import Timer

from protocol.can.frame import CanFrame

__all__ = ["ISOTP_BACKSTOP_MS", "ISOTP_TIMEOUT_MS", "IsoTpLink", "MAX_PENDING_SENDS", "MAX_FRAME_AGE_S"]

# can-isotp also logs every protocol error it reports to ``error_handler``; those are counted and
# surfaced as link errors here, so without a logging configuration they must not reach stderr
# through logging's last-resort handler (an application that configures logging still sees them).
logging.getLogger("isotp").addHandler(logging.NullHandler())

MAX_PENDING_SENDS = 256  # bulk messages queued before send() refuses
#: N_Bs (wait for a flow control) and N_Cr (wait for the next consecutive frame), ms. ISO 15765-2
#: gives 1000 ms for both, for vehicle networks with gateways in the path; both ends here share one
#: bus (or a pty) with a round trip of about a millisecond, and while a sender waits for a lost flow
#: control every later bulk message (SCREEN, SPEAKER, SIM_STATE, camera chunks) waits behind it,
#: so a lost frame costs 200 ms instead of a second. The requests above ISO-TP are re-sent anyway.
ISOTP_TIMEOUT_MS = 200
#: ISO 15765-2's N_Bs and N_Cr (ms): with a board clock (lockstep), the wall-clock limit
ISOTP_BACKSTOP_MS = 1000
#: a frame stamped longer ago than this (s) counts as arriving this long ago (a stamp from a clock that jumped)
MAX_FRAME_AGE_S = 10.0


class _LinkTimer(Timer):
    """can-isotp's ``Timer`` on an :class:`IsoTpLink`'s clock, judged at the frame in hand (module docstring)."""

    def __init__(self, timeout_s: float, link: IsoTpLink) -> None:
        super().__init__(timeout_s)
        self._link = link
        self.board_start: int | None = None

    def start(self, timeout: float | None = None) -> None:
        if timeout is not None:
            self.set_timeout(timeout)
        self.start_time = self._link.clock()
        board = self._link.board_clock
        self.board_start = board() if board is not None else None

    def is_timed_out(self) -> bool:
        if self.start_time is None:
            return False
        if self.timeout == 0:
            return True
        if self.board_start is not None and self._link.board_clock is not None:  # lockstep (module docstring)
            return (self._link.judge_board_ns() - self.board_start > self.timeout
                    or self.elapsed_ns() > ISOTP_BACKSTOP_MS * 1_000_000)
        return self.elapsed_ns() > self.timeout

    def elapsed_ns(self) -> int:
        if self.start_time is None:
            return 0
        return self._link.judge_ns() - self.start_time  # < 0 for a frame that arrived before the timer started

    def elapsed(self) -> float:
        return self.elapsed_ns() / 1e9


class _StampedLayer(isotp.TransportLayerLogic):
    """can-isotp's state machine with N_Bs and N_Cr on the link's clock (:class:`_LinkTimer`)."""

    def __init__(self, link: IsoTpLink, **kw: object) -> None:
        self._link = link
        super().__init__(**kw)  # type: ignore[arg-type]
        self.timer_rx_fc = _LinkTimer(self.params.rx_flowcontrol_timeout / 1000, link)
        self.timer_rx_cf = _LinkTimer(self.params.rx_consecutive_frame_timeout / 1000, link)

    def _process_tx(self) -> isotp.TransportLayerLogic.ProcessTxReport:
        # a flow control that just arrived is judged at its arrival (it broke the receive loop, so it is the frame
        # in hand); after that the transmitter's own timeouts are judged now (gs_isotp.c process_tx does the same)
        try:
            return super()._process_tx()
        finally:
            self._link._judge_at = None

    def _start_rx_fc_timer(self) -> None:
        self.timer_rx_fc = _LinkTimer(self.params.rx_flowcontrol_timeout / 1000, self._link)
        self.timer_rx_fc.start()

    def _start_rx_cf_timer(self) -> None:
        self.timer_rx_cf = _LinkTimer(self.params.rx_consecutive_frame_timeout / 1000, self._link)
        self.timer_rx_cf.start()


class IsoTpLink:
    """ISO-TP with normal 11-bit addressing: receive on ``rxid``, transmit on ``txid``.

    ``clock``: the link's monotonic clock (ns; default ``time.perf_counter_ns``), which its timers run
    on and received frames are stamped with (module docstring)."""

    def __init__(self, rxid: int, txid: int, fd: bool, send: Callable[[CanFrame], None], *, listen: bool = False,
                 clock: Callable[[], int] = time.perf_counter_ns, board_clock: Callable[[], int] | None = None) -> None:
        self.rxid, self.txid = rxid, txid
        self._send = send
        self.clock = clock
        #: board time (ns) for a lockstep link's timers, or None (module docstring)
        self.board_clock = board_clock
        self._rx: deque[tuple[isotp.CanMessage, int, int]] = deque()
        self._judge_at: int | None = None  # the arrival (ns) of the frame being processed; None: now
        self._judge_board_at = 0  # and its arrival in board time
        self.errors = 0
        self.flow_control_timeouts = 0  # of ``errors``: a First Frame sent that no receiver answered within ISOTP_TIMEOUT_MS
        self.last_error = ""
        params = {
            "stmin": 0,
            "blocksize": 0,
            "tx_data_length": 64 if fd else 8,
            "can_fd": bool(fd),
            "max_frame_size": 4095,
            "rx_flowcontrol_timeout": ISOTP_TIMEOUT_MS,
            "rx_consecutive_frame_timeout": ISOTP_TIMEOUT_MS,
            "wftmax": 0,
            # frames padded to 8 bytes (classic) or 64 (FD) (ISO 15765-2 padding): every frame of a
            # link then has one length, which the DBC describes (a robot's DBC, BULK_* messages)
            "tx_padding": 0xCC,
            "tx_data_min_length": 64 if fd else 8,
            "listen_mode": listen,  # True: reassemble only, never answer (reading a capture)
        }
        self.layer = _StampedLayer(
            self,
            rxfn=self._rxfn,
            txfn=self._txfn,
            address=isotp.Address(isotp.AddressingMode.Normal_11bits, rxid=rxid, txid=txid),
            error_handler=self._on_error,
            params=params,
        )

    def _rxfn(self, timeout: float) -> isotp.CanMessage | None:
        if not self._rx:
            self._judge_at = None
            return None
        msg, self._judge_at, self._judge_board_at = self._rx.popleft()
        return msg

    def use_board_clock(self, board_clock: Callable[[], int] | None) -> None:
        """Count N_Bs and N_Cr in board time from ``board_clock`` (ns; lockstep), or wall time again (None)."""
        self.board_clock = board_clock

    def judge_board_ns(self) -> int:
        """Board time (ns) a timeout is judged at: the board time the frame in hand arrived at, or now."""
        assert self.board_clock is not None
        return self.board_clock() if self._judge_at is None else self._judge_board_at

    def judge_ns(self) -> int:
        """The time (ns, :attr:`clock`) a timeout is judged at: the arrival of the frame in hand, or now."""
        return self.clock() if self._judge_at is None else self._judge_at

    def arrival_ns(self, frame: CanFrame) -> int:
        """When ``frame`` arrived on :attr:`clock` (ns): now, less its age by ``frame.timestamp`` (0..MAX_FRAME_AGE_S)."""
        now = self.clock()
        if frame.timestamp is None:
            return now
        age = min(max(time.time() - frame.timestamp, 0.0), MAX_FRAME_AGE_S)
        return now - int(age * 1e9)

    def _txfn(self, msg: isotp.CanMessage) -> None:
        self._send(CanFrame(msg.arbitration_id, bytes(msg.data), is_fd=bool(msg.is_fd)))

    def _on_error(self, error: Exception) -> None:
        self.errors += 1
        if isinstance(error, isotp.errors.FlowControlTimeoutError):
            self.flow_control_timeouts += 1
        self.last_error = f"{type(error).__name__}: {error}"

    def feed(self, frame: CanFrame, at_ns: int | None = None) -> None:
        """A received frame with identifier ``rxid``, arrived at ``at_ns`` (:attr:`clock`, ns; default
        :meth:`arrival_ns`). Bounded: a flood beyond 4096 waiting frames is dropped (counted in ``errors``)."""
        if len(self._rx) < 4096:
            at = self.arrival_ns(frame) if at_ns is None else at_ns
            board_at = self.board_clock() if self.board_clock is not None else 0
            self._rx.append((isotp.CanMessage(frame.arbitration_id, len(frame.data), bytes(frame.data), False, frame.is_fd),
                             at, board_at))
        else:
            self.errors += 1

    def send(self, sdu: bytes) -> None:
        """Queue one service data unit (``BufferError`` when ``MAX_PENDING_SENDS`` are waiting)."""
        if self.layer.tx_queue.qsize() >= MAX_PENDING_SENDS:
            raise BufferError(f"ISO-TP: {MAX_PENDING_SENDS} bulk messages already waiting")
        self.layer.send(sdu)

    def poll(self) -> list[bytes]:
        """Advance the state machine; the service data units completed since the last poll."""
        try:
            self.layer.process()
        except Exception as e:  # never let a malformed frame take the loop down
            self._on_error(e)
        finally:
            self._judge_at = None
        out: list[bytes] = []
        while self.layer.available():
            data = self.layer.recv()
            if data is not None:
                out.append(bytes(data))
        return out

    @property
    def busy(self) -> bool:
        """True while a transfer is in progress either way (poll again soon for its timers)."""
        return bool(self.layer.transmitting() or self.layer.is_rx_active() or self._rx)
