"""Non-blocking byte pipes under the board's serial transport: a pty pair it creates, or a port / pyserial URL.

No framing and no timing here (:mod:`firmware_sim.transports.serial` frames; :mod:`protocol.wiremodel`
times): a port reads what is there and writes what fits, never blocking. Also used by the C firmware
launcher's relay (:mod:`firmware_sim.cfirmware.launcher`).
"""

from __future__ import annotations

import errno
import os
import tty

import serial

__all__ = ["BytePort", "PtyPort", "SerialPort", "open_port"]


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
