"""The CAN wire engine shared by both ends (sans-I/O): frames in -> messages out, messages in -> frames out.

:class:`CanEngine` is everything between a CAN bus and the link seam's items
(:class:`protocol.framing.Frame` / :class:`~protocol.framing.DecodeError`) for one node, written
once for the host and the board:

* receiving, ``feed(frame)``: a frame on the node's bulk identifier goes to ISO-TP
  (:class:`protocol.can.isotp_link.IsoTpLink`), every other one to the fixed-layout reassembler
  (:class:`protocol.can.decoder.CanDecoder`, which ignores what is not addressed to this end);
* sending, ``send(msg, seq)``: a message with a fixed layout in the link's frame kind becomes its
  frames (:func:`protocol.can.codec.encode_fixed`), any other one an ISO-TP unit
  (:func:`protocol.can.codec.encode_bulk`); every frame to put on the bus goes to ``emit`` (the
  end's transmit queue: the host's is FIFO, the board's a CAN controller's priority order);
* ``poll()`` advances ISO-TP (its flow-control and consecutive-frame timers are can-isotp's own:
  call it whenever something arrived and every few ms while :attr:`busy`) and returns the bulk
  messages it completed, plus one error item per ISO-TP error not yet reported.

What differs between the ends is policy and stays with them: the board's periodic bulk reports
(newest wins) and its NACK trimming; ``excuse_flow_control`` lets the board say that flow-control
timeouts of reports nobody listened to are no link errors. Both ends use the robot's layout table
(:func:`protocol.can.layouts.can_layouts`); :meth:`set_layouts` switches it (the host, after CAPS).
"""

from __future__ import annotations

import time
from collections.abc import Callable

from protocol.can.codec import Sender, encode_bulk, encode_fixed, is_fixed
from protocol.can.decoder import CanDecodeError, CanDecoder, CanErrorKind, CanItem, as_frame_items
from protocol.can.frame import CanFrame
from protocol.can.ids import bulk_ids
from protocol.can.isotp_link import IsoTpLink
from protocol.can.layouts import CanLayouts, can_layouts
from protocol.framing import DecodeError, Frame
from protocol.messages import Message

__all__ = ["CanEngine"]


class CanEngine:
    """One end (``role`` ``"host"`` or ``"board"``) of the link to board ``node`` on a classic (or FD) bus.

    ``emit(frame)`` is called for every frame to transmit, in the order they must go out (the
    parts of one message in part order). Never raises on received frames (problems become
    :class:`~protocol.framing.DecodeError` items); :meth:`send` raises
    :class:`protocol.codec.PayloadError` for a message that cannot be encoded and ``BufferError``
    when ISO-TP already holds ``MAX_PENDING_SENDS`` units.
    """

    def __init__(self, node: int, role: str, fd: bool, emit: Callable[[CanFrame], None],
                 layouts: CanLayouts | None = None, clock: Callable[[], int] | None = None) -> None:
        if role not in ("host", "board"):
            raise ValueError(f"role must be 'host' or 'board', got {role!r}")
        self.node, self.role, self.fd = node, role, fd
        self._emit = emit
        self.layouts: CanLayouts = can_layouts() if layouts is None else layouts
        self.sender = Sender.HOST if role == "host" else Sender.BOARD
        to_board, to_host = bulk_ids(node)
        self.bulk_rx_id, self.bulk_tx_id = (to_host, to_board) if role == "host" else (to_board, to_host)
        self.decoder = CanDecoder(node, role, self.layouts)
        #: ISO-TP's clock (ns; :class:`protocol.can.isotp_link.IsoTpLink`): ``time.perf_counter_ns`` unless given
        self.clock: Callable[[], int] = clock or time.perf_counter_ns
        #: board time (ns) for ISO-TP's timers on a lockstep link (:meth:`use_board_clock`), else None
        self.board_clock: Callable[[], int] | None = None
        self.isotp = IsoTpLink(rxid=self.bulk_rx_id, txid=self.bulk_tx_id, fd=fd, send=emit, clock=self.clock)
        self._errors_reported = 0  # ISO-TP errors already reported as items (or excused)
        #: given the flow-control timeouts a poll saw, how many of them are no link error (default none)
        self.excuse_flow_control: Callable[[int], int] = lambda n: 0

    def reset(self) -> None:
        """A new connection: empty reassembly and ISO-TP state (the layouts stay)."""
        self.decoder = CanDecoder(self.node, self.role, self.layouts)
        self.isotp = IsoTpLink(rxid=self.bulk_rx_id, txid=self.bulk_tx_id, fd=self.fd, send=self._emit, clock=self.clock,
                               board_clock=self.board_clock)

    def use_board_clock(self, board_clock: Callable[[], int] | None) -> None:
        """ISO-TP's N_Bs and N_Cr in board time from ``board_clock`` (ns; a lockstep link), or wall time (None):
        :mod:`protocol.can.isotp_link`."""
        self.board_clock = board_clock
        self.isotp.use_board_clock(board_clock)
        self._errors_reported = 0

    def set_layouts(self, layouts: CanLayouts) -> None:
        """Speak ``layouts`` from now on (the sequence unwrapping reference carries over)."""
        if layouts is self.layouts:
            return
        self.layouts = layouts
        last = self.decoder.last_seq
        self.decoder = CanDecoder(self.node, self.role, layouts)
        self.decoder.last_seq = last

    # --- receiving ---------------------------------------------------------------------------

    def feed(self, frame: CanFrame) -> list[Frame | DecodeError]:
        """One received frame; the whole messages (and errors) it completes, in order."""
        if frame.arbitration_id == self.bulk_rx_id and not frame.is_extended_id:
            self.isotp.feed(frame)
            return self.poll()
        return as_frame_items(self.decoder.feed(frame))

    def feed_many(self, frames: list[CanFrame]) -> list[Frame | DecodeError]:
        """Several frames at once (ISO-TP is polled once, after the last)."""
        items: list[CanItem | CanDecodeError] = []
        bulk = False
        for frame in frames:
            if frame.arbitration_id == self.bulk_rx_id and not frame.is_extended_id:
                self.isotp.feed(frame)
                bulk = True
            else:
                items += self.decoder.feed(frame)
        out = as_frame_items(items)
        return out + self.poll() if bulk or self.isotp.busy else out

    def poll(self) -> list[Frame | DecodeError]:
        """Advance ISO-TP: the bulk messages it completed and its new errors (see the module docstring)."""
        isotp = self.isotp
        timeouts = isotp.flow_control_timeouts
        sdus = isotp.poll()
        new_timeouts = isotp.flow_control_timeouts - timeouts
        if new_timeouts:
            self._errors_reported += max(0, min(new_timeouts, self.excuse_flow_control(new_timeouts)))
        items: list[CanItem | CanDecodeError] = [self.decoder.feed_bulk(sdu) for sdu in sdus]
        if isotp.errors > self._errors_reported:
            self._errors_reported = isotp.errors
            items.append(CanDecodeError(CanErrorKind.BULK, f"ISO-TP: {isotp.last_error}"))
        return as_frame_items(items)

    @property
    def busy(self) -> bool:
        """True while an ISO-TP transfer is under way either way (poll again within a few ms)."""
        return self.isotp.busy

    @property
    def bulk_waiting(self) -> int:
        """ISO-TP units queued or in transfer (not yet all frames emitted)."""
        layer = self.isotp.layer
        return layer.tx_queue.qsize() + (1 if layer.transmitting() else 0)

    # --- sending -----------------------------------------------------------------------------

    def is_fixed(self, msg: Message) -> bool:
        """True when ``msg`` goes as fixed-layout frames in this link's frame kind."""
        return is_fixed(msg, self.fd, self.layouts)

    def send(self, msg: Message, seq: int) -> None:
        """Encode ``msg`` with ``seq``: fixed frames to ``emit`` now, or an ISO-TP unit (its frames
        are emitted as ISO-TP runs: call :meth:`poll`)."""
        if self.is_fixed(msg):
            for f in encode_fixed(msg, seq, self.node, self.fd, self.sender, self.layouts):
                self._emit(f)
        else:
            self.send_bulk(self.encode_bulk(msg, seq))

    def encode_bulk(self, msg: Message, seq: int) -> bytes:
        """``msg`` as an ISO-TP unit in this link's schema (for a caller that queues units itself)."""
        return encode_bulk(msg, seq, self.layouts.schema)

    def send_bulk(self, sdu: bytes) -> None:
        """Queue one ISO-TP unit (``BufferError`` when too many wait)."""
        self.isotp.send(sdu)
