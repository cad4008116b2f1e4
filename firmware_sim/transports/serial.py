"""The board's serial transport: a pty pair it creates, or an existing port / pyserial URL.

:class:`SerialBoardTransport` (the :class:`firmware_sim.transports.base.BoardTransport`
for serial) frames messages with :mod:`protocol.framing` (COBS + CRC), models wire
time and writes the JSON-Lines frame log. Under it, :class:`PtyPort` / :class:`SerialPort`
are non-blocking byte pipes. The wire-time model (:class:`WireModel`): a pty ignores baud
rates, so with ``baud`` set every byte costs 10 bit times in each direction (start + 8
data + stop).
"""

from __future__ import annotations

import errno
import os
import sys
import tty
from collections import deque

from typing import IO

import serial

from firmware_sim.transports.base import BoardTransport
from protocol import framelog
from protocol.codec import WIRE_SCHEMA_16, PayloadError, WireSchema, msg_type_of, schema_for
from protocol.framing import DecodeError, Frame, FrameDecoder, encode_frame
from protocol.messages import Message

__all__ = ["BytePort", "PtyPort", "SerialBoardTransport", "SerialPort", "WireModel", "open_port"]


class BytePort:
    """Non-blocking byte pipe with an optional fd for select()."""

    name: str = ""

    def fileno(self) -> int | None:
        raise NotImplementedError

    def read(self) -> bytes:
        """Bytes available now (b"" if none)."""
        raise NotImplementedError

    def write(self, data: bytes) -> int:
        """Write what fits without blocking; returns the count written."""
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class PtyPort(BytePort):
    """The master side of a pty pair created by the board; the slave stays open so it persists."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)  # no echo, no line editing: bytes pass untouched
        os.set_blocking(self.master, False)
        self.name = os.ttyname(self.slave)

    def fileno(self) -> int:
        return self.master

    def read(self) -> bytes:
        try:
            return os.read(self.master, 65536)
        except BlockingIOError:
            return b""
        except OSError as e:
            if e.errno == errno.EIO:  # no slave open (cannot happen while we hold it)
                return b""
            raise

    def write(self, data: bytes) -> int:
        try:
            return os.write(self.master, data)
        except BlockingIOError:
            return 0

    def close(self) -> None:
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


class SerialPort(BytePort):
    """An existing serial device path or any pyserial URL (``socket://host:port``, ``loop://`` ...)."""

    def __init__(self, url: str, baud: int) -> None:
        self.ser = serial.serial_for_url(url, baudrate=baud, timeout=0, write_timeout=0)
        self.name = url

    def fileno(self) -> int | None:
        try:
            return self.ser.fileno()
        except Exception:
            sock = getattr(self.ser, "_socket", None)
            return sock.fileno() if sock is not None else None

    def read(self) -> bytes:
        return bytes(self.ser.read(65536))

    def write(self, data: bytes) -> int:
        try:
            n = self.ser.write(data)
        except serial.SerialTimeoutException:
            return 0
        return len(data) if n is None else int(n)

    def close(self) -> None:
        self.ser.close()


def open_port(port: str, baud: int | None) -> BytePort:
    """``"pty"`` -> a new pty pair; anything else -> pyserial ``serial_for_url``."""
    if port == "pty":
        return PtyPort()
    return SerialPort(port, baud or 115200)


class WireModel:
    """Serialises bytes on a modelled UART: each chunk finishes ``10 * n / baud`` s after the previous."""

    def __init__(self, baud: int | None) -> None:
        self.byte_time = 10.0 / baud if baud else 0.0
        self.free_at = 0.0
        self.queue: deque[tuple[float, bytes]] = deque()
        self.bytes_queued = 0

    def push(self, now: float, data: bytes) -> None:
        if self.byte_time:
            self.free_at = max(self.free_at, now) + len(data) * self.byte_time
            release = self.free_at
        else:
            release = now
        self.queue.append((release, data))
        self.bytes_queued += len(data)

    def next_release(self) -> float | None:
        return self.queue[0][0] if self.queue else None

    def pop_ready(self, now: float) -> bytes:
        out = bytearray()
        while self.queue and self.queue[0][0] <= now:
            out += self.queue.popleft()[1]
        self.bytes_queued -= len(out)
        return bytes(out)


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
        self.rx_wire = WireModel(baud)
        self.tx_wire = WireModel(baud)
        self.tx_pending = bytearray()
        self.unsendable = 0  # messages that did not encode (reported on stderr, not sent)
        self._log: IO[str] | None = None
        if log_path:
            try:
                self._log = open(log_path, "w", buffering=1, encoding="utf-8")
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
        if self._log is not None and items:
            t = self.log_time()
            for item in items:
                self._log.write(framelog.to_line(framelog.record("rx", t, item.raw, item)) + "\n")
        return items

    def queue(self, msg: Message, seq: int, now: float) -> None:
        try:
            raw = encode_frame(msg, seq, self.schema)
        except PayloadError as e:  # nothing the board sends may take it down: say so (once), send nothing
            self.unsendable += 1
            if self.unsendable == 1:
                print(f"board: cannot send {type(msg).__name__}: {e} (further ones counted at exit)",
                      file=sys.stderr, flush=True)
            return
        if self._log is not None:
            item = Frame(seq & 0xFFFF, msg_type_of(msg), msg, raw)
            self._log.write(framelog.to_line(framelog.record("tx", self.log_time(), raw, item)) + "\n")
        self.tx_wire.push(now, raw)

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
        return self.tx_wire.free_at - now if self.tx_wire.byte_time else 0.0

    def next_io_time(self) -> float | None:
        times = [t for t in (self.rx_wire.next_release(), self.tx_wire.next_release()) if t is not None]
        return min(times) if times else None

    def close(self) -> None:
        if self._log is not None:
            self._log.close()
            self._log = None
        self.port.close()
