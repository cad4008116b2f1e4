"""Byte transports for the board: a pty pair it creates, or an existing port / pyserial URL.

Also the wire-time model: a pty ignores baud rates, so with ``baud`` set every
byte costs 10 bit times in each direction (start + 8 data + stop).
"""

from __future__ import annotations

import errno
import os
import tty
from collections import deque

import serial

__all__ = ["FdLink", "Link", "SerialLink", "WireModel", "open_link"]


class Link:
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


class FdLink(Link):
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


class SerialLink(Link):
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


def open_link(spec: str, baud: int | None) -> Link:
    """``"pty"`` -> a new pty pair; anything else -> pyserial ``serial_for_url``."""
    if spec == "pty":
        return FdLink()
    return SerialLink(spec, baud or 115200)


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
