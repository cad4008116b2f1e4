"""The board's serial transport: a thin adapter from a byte port to the serial wire engines.

:class:`SerialBoardTransport` (the :class:`firmware_sim.transports.base.BoardTransport` for serial)
reads and writes a non-blocking byte port (:mod:`firmware_sim.transports.ports`: a pty pair it
creates, or an existing port / pyserial URL) and leaves everything else to the sans-I/O pieces of
``protocol/``: framing (:func:`protocol.framing.encode_frame`, :class:`protocol.framing.FrameDecoder`),
the wire-time model in each direction (:class:`protocol.wiremodel.WireModel`: with ``baud`` set,
every byte costs 10 bit times) and the JSON-Lines frame log (:mod:`protocol.logfile`).
"""

from __future__ import annotations

import sys

from firmware_sim.transports.base import BoardTransport
from firmware_sim.transports.ports import open_port
from protocol.codec import WIRE_SCHEMA_16, PayloadError, WireSchema, schema_for
from protocol.framing import FRAME_DELIMITER, DecodeError, Frame, FrameDecoder, encode_frame
from protocol.logfile import FrameLogWriter, open_frame_log
from protocol.messages import Message
from protocol.wiremodel import WireModel

__all__ = ["SerialBoardTransport"]


class SerialBoardTransport(BoardTransport):
    """Protocol v1 over a pty pair (``port == "pty"``) or a serial port / pyserial URL.

    ``baud`` (None = no model) delays bytes by their wire time in both directions;
    ``log_path`` gets one JSON-Lines record per frame both ways, stamped with :attr:`log_time`;
    ``servo_count`` (the robot's) picks the wire schema (default: the u16 one).
    """

    def __init__(self, port: str, *, baud: int | None = None, log_path: str | None = None,
                 servo_count: int | None = None) -> None:
        super().__init__()
        self.schema: WireSchema = WIRE_SCHEMA_16 if servo_count is None else schema_for(servo_count)
        self.port = open_port(port, baud)
        self.name = self.port.name
        self.decoder = FrameDecoder(schema=self.schema)
        self.rx_wire = WireModel(baud, FRAME_DELIMITER)  # frame by frame: one read may hold several
        self.tx_wire = WireModel(baud)
        self.tx_pending = bytearray()
        self.unsendable = 0  # messages that did not encode (reported on stderr, not sent)
        self.framelog: FrameLogWriter | None = None
        if log_path:
            try:
                self.framelog = open_frame_log(log_path, "serial", schema=self.schema)
            except OSError:
                self.port.close()
                raise

    def fileno(self) -> int | None:
        return self.port.fileno()

    def receive(self, now: float, *, read: bool = True) -> list[Frame | DecodeError]:
        if read:
            data = self.port.read()
            if data:
                self.rx_wire.push(now, data)
        data = self.rx_wire.pop_ready(now)
        if not data:
            return []
        items = self.decoder.feed(data)
        if self.framelog is not None and items:
            t = self.log_time()
            for item in items:
                self.framelog.write_serial("rx", t, item.raw, item)
        return items

    def queue(self, msg: Message, seq: int, now: float) -> bool:
        try:
            raw = encode_frame(msg, seq, self.schema)
        except PayloadError as e:  # nothing the board sends may take it down: say so (once), send nothing
            self.unsendable += 1
            if self.unsendable == 1:
                print(f"board: cannot send {type(msg).__name__}: {e} (further ones counted at exit)",
                      file=sys.stderr, flush=True)
            return False
        if self.framelog is not None:
            self.framelog.write_serial("tx", self.log_time(), raw)  # as the wire bytes decode
        self.tx_wire.push(now, raw)
        return True

    def exit_note(self) -> str | None:
        return f"{self.unsendable} message(s) could not be encoded and were not sent" if self.unsendable else None

    def flush(self, now: float) -> None:
        self.tx_pending += self.tx_wire.pop_ready(now)
        if self.tx_pending:
            n = self.port.write(bytes(self.tx_pending))
            del self.tx_pending[:n]

    @property
    def backlog(self) -> int:
        return self.tx_wire.bytes_queued + len(self.tx_pending)

    @property
    def wants_write(self) -> bool:
        return bool(self.tx_pending)

    def tx_busy_s(self, now: float) -> float:
        return float(self.tx_wire.busy_s(now))

    def next_io_time(self) -> float | None:
        times = [t for t in (self.rx_wire.next_release(), self.tx_wire.next_release()) if t is not None]
        return min(times) if times else None

    def close(self) -> None:
        # what the board queued (and logged as sent) goes out now, as far as the port takes it without
        # blocking: a frame in the log is a frame that went to the wire
        self.flush(float("inf"))
        if self.framelog is not None:
            self.framelog.close()
            self.framelog = None
        self.port.close()
