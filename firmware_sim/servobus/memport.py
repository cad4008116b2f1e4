"""An in-memory serial port the vendor SDKs' packet handlers can use (no pty, no time).

:class:`MemPort` has what ``scservo_sdk``/``dynamixel_sdk`` call on a ``PortHandler`` (``readPort``,
``writePort``, ``setPacketTimeout``, ``isPacketTimeout``, ``is_using``, ``tx_time_per_byte``, ...)
and what :class:`~firmware_sim.servobus.ports.TimedPortMixin` adds (``timed_out``,
``discard_input``). Every packet written is handed to ``answer`` (bytes -> the bus's answer
bytes), whose answer is then read back; a wait times out as soon as nothing is left to read, so a
run is deterministic and never sleeps. The fuzz targets (:mod:`firmware_sim.servobus.fuzz`) answer
with garbage, partial and well-formed packets.
"""

from __future__ import annotations

from collections.abc import Callable

__all__ = ["MemPort"]

#: unread answer bytes kept at most (more is dropped, as a UART's receive buffer overflows)
MAX_PENDING = 64 * 1024


class MemPort:
    """A port whose other end is the function ``answer``; ``written`` keeps every packet sent."""

    def __init__(self, answer: Callable[[bytes], bytes], baud: int = 1_000_000) -> None:
        self.answer = answer
        self.port_name = "mem"
        self.baudrate = baud
        self.is_open = True
        self.is_using = False
        self.timed_out = False
        self.tx_time_per_byte = 10_000.0 / baud  # ms
        self.packet_start_time = 0.0
        self.packet_timeout = 0.0
        self.latency_ms = 0.0
        self.rx = bytearray()
        self.written: list[bytes] = []

    # -- what the SDKs call ------------------------------------------------------------------------
    def openPort(self) -> bool:  # noqa: N802 - the SDKs' names
        return True

    def closePort(self) -> None:  # noqa: N802
        self.is_open = False

    def clearPort(self) -> None:  # noqa: N802
        self.rx.clear()

    def setBaudRate(self, baud: int) -> bool:  # noqa: N802
        self.baudrate = baud
        return True

    def getBaudRate(self) -> int:  # noqa: N802
        return self.baudrate

    def getBytesAvailable(self) -> int:  # noqa: N802
        return len(self.rx)

    def readPort(self, length: int) -> bytes:  # noqa: N802
        n = max(0, int(length))
        out = bytes(self.rx[:n])
        del self.rx[:n]
        return out

    def writePort(self, packet: object) -> int:  # noqa: N802
        data = bytes(packet)  # type: ignore[call-overload]
        self.written.append(data)
        del self.written[:-64]
        self.rx += self.answer(data)
        del self.rx[MAX_PENDING:]
        return len(data)

    def setPacketTimeout(self, packet_length: int) -> None:  # noqa: N802
        self.timed_out = False

    def setPacketTimeoutMillis(self, msec: float) -> None:  # noqa: N802
        self.timed_out = False

    def isPacketTimeout(self) -> bool:  # noqa: N802
        if not self.rx:
            self.timed_out = True
        return self.timed_out

    def getCurrentTime(self) -> float:  # noqa: N802
        return 0.0

    def getTimeSinceStart(self) -> float:  # noqa: N802
        return 0.0

    # -- TimedPortMixin's additions ----------------------------------------------------------------
    def discard_input(self) -> None:
        self.rx.clear()
