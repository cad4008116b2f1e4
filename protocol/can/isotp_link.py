"""One ISO-TP (ISO 15765-2) link over CAN frames, driven by polling (can-isotp's TransportLayerLogic).

Shared by both ends: the host drives it from its asyncio loop, the board from its select loop, and
the fuzzer and the log decoder in listen mode. It does no I/O and starts no thread: frames for the
link are pushed in with :meth:`IsoTpLink.feed`, frames it emits go to ``send``,
and :meth:`poll` advances it (call it whenever something arrived and every few ms while
:attr:`busy`). Block size 0 and STmin 0: one flow control per message, no pacing; frames padded to 8 (FD: 64) bytes.
The one clocked piece of ``protocol/``: ISO-TP's flow-control and consecutive-frame timeouts are
can-isotp's own timers (it reads the monotonic clock inside ``process``).
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable

import isotp

from protocol.can.frame import CanFrame

__all__ = ["ISOTP_TIMEOUT_MS", "IsoTpLink", "MAX_PENDING_SENDS"]

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


class IsoTpLink:
    """ISO-TP with normal 11-bit addressing: receive on ``rxid``, transmit on ``txid``."""

    def __init__(self, rxid: int, txid: int, fd: bool, send: Callable[[CanFrame], None], *, listen: bool = False) -> None:
        self.rxid, self.txid = rxid, txid
        self._send = send
        self._rx: deque[isotp.CanMessage] = deque()
        self.errors = 0
        self.flow_control_timeouts = 0  # of ``errors``: a First Frame sent that no receiver answered within 1 s
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
        self.layer = isotp.TransportLayerLogic(
            rxfn=self._rxfn,
            txfn=self._txfn,
            address=isotp.Address(isotp.AddressingMode.Normal_11bits, rxid=rxid, txid=txid),
            error_handler=self._on_error,
            params=params,
        )

    def _rxfn(self, timeout: float) -> isotp.CanMessage | None:
        return self._rx.popleft() if self._rx else None

    def _txfn(self, msg: isotp.CanMessage) -> None:
        self._send(CanFrame(msg.arbitration_id, bytes(msg.data), is_fd=bool(msg.is_fd)))

    def _on_error(self, error: Exception) -> None:
        self.errors += 1
        if isinstance(error, isotp.errors.FlowControlTimeoutError):
            self.flow_control_timeouts += 1
        self.last_error = f"{type(error).__name__}: {error}"

    def feed(self, frame: CanFrame) -> None:
        """A received frame with identifier ``rxid`` (bounded: a flood beyond 4096 frames is dropped)."""
        if len(self._rx) < 4096:
            self._rx.append(isotp.CanMessage(frame.arbitration_id, len(frame.data), bytes(frame.data), False, frame.is_fd))
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
