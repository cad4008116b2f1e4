"""python-can's SLCAN bus with one change: a read takes every byte the port already holds.

python-can 4.6.1's ``slcanBus._read`` fetches one byte per ``serial.read(1)`` (a ``select`` and a
``read`` system call per byte, ~25 per classic frame, ~140 per 64-byte FD frame): on a SLCAN link
that is where the host spends most of its time, and it is what makes a lockstep SLCAN run ~3x
slower than a pty run and adds milliseconds to every telemetry report in realtime. This is
python-can issue #2027; upstream fixed it in #2028 (merged February 2026, not in a release yet,
4.6.1 being the newest on PyPI). :class:`BufferedSlcanBus` overrides only ``_read``, written here
from the same idea: read ``in_waiting`` bytes (at least one, within the timeout), return the first
complete response line (``\\r``, or ``\\a`` for an error) and keep the rest for the next call.
Parsing, opening, sending and closing stay python-can's. Remove it once python-can > 4.6.1 is
required.
"""

from __future__ import annotations

import serial
from can.exceptions import error_check
from can.interfaces.slcan import slcanBus

__all__ = ["BufferedSlcanBus"]


class BufferedSlcanBus(slcanBus):
    """``can.Bus(interface="slcan", ...)`` with buffered reads (same arguments, same behaviour)."""

    def has_buffered_line(self) -> bool:
        """True while a whole line waits in the buffer. The port's fd no longer shows it as
        readable (its bytes were read), so a reader woken by the fd must keep receiving while
        this is true -- also after a ``recv`` that returned None because the line was an
        adapter response ("z", "\\r") or a frame the filters dropped."""
        return self._buffer.find(b"\r") >= 0 or self._buffer.find(b"\a") >= 0

    def _line(self) -> str | None:
        """The first whole line in the buffer (terminator included), taken out of it; else None."""
        buf = self._buffer
        ends = [i for i in (buf.find(b"\r"), buf.find(b"\a")) if i >= 0]  # _OK, _ERROR
        if not ends:
            return None
        end = min(ends) + 1
        line = bytes(buf[:end]).decode()
        del buf[:end]
        return line

    def _read(self, timeout: float | None) -> str | None:
        deadline = serial.Timeout(timeout)
        with error_check("Could not read from serial device"):
            while True:
                line = self._line()
                if line is not None:
                    return line
                port = self.serialPortOrig
                self._buffer.extend(port.read(max(1, port.in_waiting)))
                if deadline.expired():
                    return self._line()  # the read above may have completed one
