"""The SDKs' serial port objects with the timing this board needs (same interface, LeRobot-style patch).

Both SDKs (``scservo_sdk.PortHandler``, ``dynamixel_sdk.PortHandler``) time an answer out after its
bytes' wire time plus ``2 * LATENCY_TIMER + 2`` ms, a module constant, on the wall clock
(``time.time``), and poll the port in a busy loop. :class:`TimedPortMixin` keeps their packet code
and changes only that: a per-port latency (``latency_ms``), the monotonic clock, a ``timed_out``
flag the bus reads to tell a timeout from a checksum error, and a read that waits on the file
descriptor (at most 0.5 ms at a time) instead of spinning while nothing has arrived.

:meth:`TimedPortMixin.open_at` opens the port at a baud rate and raises
:class:`~firmware_sim.servobus.base.BusOpenError` with one line when the port is missing or the
adapter refuses the rate (the SDKs return False for a rate outside their table).
"""

from __future__ import annotations

import os
import select
import time
from typing import Any

from firmware_sim.servobus.base import BusOpenError

__all__ = ["TimedPortMixin", "dxl_port", "sts_port"]


class TimedPortMixin:
    """Mix in before an SDK ``PortHandler``; ``latency_ms`` per port (ms)."""

    latency_ms: float = 16.0
    timed_out: bool = False
    ser: Any
    tx_time_per_byte: float
    packet_start_time: float
    packet_timeout: float

    def getCurrentTime(self) -> float:  # noqa: N802 - the SDK's name
        """Monotonic milliseconds (the SDK's is the wall clock, which may jump)."""
        return time.monotonic() * 1000.0

    def setPacketTimeout(self, packet_length: int) -> None:  # noqa: N802
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = self.tx_time_per_byte * packet_length + self.latency_ms * 2.0 + 2.0
        self.timed_out = False

    def setPacketTimeoutMillis(self, msec: float) -> None:  # noqa: N802
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = msec
        self.timed_out = False

    def isPacketTimeout(self) -> bool:  # noqa: N802
        if self.getCurrentTime() - self.packet_start_time > self.packet_timeout:
            self.packet_timeout = 0
            self.timed_out = True
            return True
        return False

    def readPort(self, length: int) -> bytes:  # noqa: N802
        data = self.ser.read(length)
        if data:
            return bytes(data)
        left_ms = self.packet_timeout - (self.getCurrentTime() - self.packet_start_time)
        try:
            fd = self.ser.fileno()
        except Exception:  # noqa: BLE001 - a port without a descriptor (a pyserial URL): poll as the SDK does
            return b""
        if left_ms > 0:
            select.select([fd], [], [], min(left_ms / 1000.0, 0.0005))
        return bytes(self.ser.read(length))

    def discard_input(self) -> None:
        """Drop whatever is waiting in the receive buffer (stale answers)."""
        try:
            self.ser.reset_input_buffer()
        except Exception:  # noqa: BLE001 - a vanished adapter: the next read reports it
            pass

    def open_at(self, baud: int) -> None:
        """Open at ``baud``; :class:`BusOpenError` naming the port and why."""
        name = getattr(self, "port_name", "?")
        if not _is_tty(name):
            raise BusOpenError(f"{name} is not a serial port (a USB serial adapter such as /dev/ttyUSB0, or a pty)")
        try:
            ok = self.setBaudRate(baud)  # type: ignore[attr-defined]
        except Exception as e:  # noqa: BLE001 - serial.SerialException, OSError, ValueError: one line
            raise BusOpenError(f"cannot open it at {baud} baud: {e}") from None
        if ok:  # a USB adapter's latency timer (FTDI: 16 ms) is longer than a tick: ask for low latency
            try:
                self.ser.set_low_latency_mode(True)
            except Exception:  # noqa: BLE001 - best effort: not a tty that has it (a pty), no permission
                pass
        if not ok:
            raise BusOpenError(f"cannot open it at {baud} baud: the serial adapter (its driver, as the vendor SDK "
                               "knows it) does not offer that rate")


def _is_tty(name: str) -> bool:
    """False only for a path that exists and is no terminal device (``/dev/null``, a file): pyserial would
    fail on it with a raw ioctl error. A missing path or one this process may not open: True (the open
    names the real reason); a pyserial URL or a Windows port name: True."""
    if not os.path.exists(name):
        return True
    try:
        fd = os.open(name, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError:
        return True
    try:
        return os.isatty(fd)
    finally:
        os.close(fd)


def sts_port(name: str, latency_ms: float) -> Any:
    """A Feetech SDK port on ``name`` (not opened)."""
    from scservo_sdk import PortHandler

    cls = type("StsPort", (TimedPortMixin, PortHandler), {})
    p = cls(name)
    p.latency_ms = latency_ms
    return p


def dxl_port(name: str, latency_ms: float) -> Any:
    """A ROBOTIS SDK port on ``name`` (not opened)."""
    from dynamixel_sdk import PortHandler

    cls = type("DxlPort", (TimedPortMixin, PortHandler), {})
    p = cls(name)
    p.latency_ms = latency_ms
    return p
