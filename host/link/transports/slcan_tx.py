"""Non-blocking SLCAN output: whole Lawicel lines, written as far as the serial port takes them.

Why not python-can's ``slcanBus.send``: on a full port (the board, or a real adapter, is not
reading) it cannot send without blocking the caller. With ``timeout=0`` pyserial's POSIX
``write`` spins on EAGAIN until the port has room (pyserial issue #280, open), which freezes the
host's event loop -- telemetry, the request timers and the run's silence watchdog included -- for
as long as the other end does not read; and when the port takes only part of a line, pyserial
returns the count and python-can ignores it, so the rest of the line is lost and the next line is
glued onto the stub (the adapter refuses both). With a positive timeout it still spins until the
timeout and may leave a partial line behind. So the host formats the lines itself with the
SLCAN engine shared with the board (:func:`protocol.can.slcan.format_frame`: the same
``t``/``d``/``b`` lines python-can's ``send`` builds) and writes them to the
port's file descriptor (``bus.fileno()``, non-blocking as pyserial opens it), keeping whatever
did not fit for the next write. Receiving stays python-can's.
"""

from __future__ import annotations

import errno
import os

import can

from protocol.can.pycan import from_can_message
from protocol.can.slcan import format_frame

__all__ = ["SlcanWriter", "slcan_line"]


def slcan_line(msg: can.Message) -> bytes:
    """The SLCAN line (``\\r`` included) python-can's ``slcanBus.send`` would write for ``msg``.

    Standard (11-bit) data frames only, which is all the host sends: ``tIIIL<hex>`` (classic,
    L = length 0..8), ``dIIIL<hex>`` / ``bIIIL<hex>`` (FD without / with bit-rate switch, L = the
    FD DLC in hex). Raises ``ValueError`` for an extended or remote frame.
    """
    if msg.is_extended_id or msg.is_remote_frame:
        raise ValueError("the host's SLCAN output carries standard data frames only")
    return format_frame(from_can_message(msg), brs=bool(msg.is_fd and msg.bitrate_switch))


class SlcanWriter:
    """Bytes of whole SLCAN lines waiting for the port ``fd``; :meth:`write` never blocks.

    ``pending`` is what the port has not taken yet (a line is either queued whole or not at all,
    and a line the port took in part is finished by the next :meth:`write`, so the adapter always
    sees complete lines). Raises ``OSError`` from :meth:`write` when the port is gone (EIO: the
    other end closed the pty).
    """

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.pending = bytearray()
        self.short_writes = 0  # writes the port took only in part (or not at all): it was full

    def push(self, line: bytes) -> None:
        """Queue one whole line (call :meth:`write` to send)."""
        self.pending += line

    def write(self) -> bool:
        """Write as much of :attr:`pending` as the port takes now; True when nothing is left."""
        while self.pending:
            try:
                n = os.write(self.fd, self.pending)
            except (BlockingIOError, InterruptedError):
                n = 0
            except OSError as e:
                if e.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
                    n = 0
                else:
                    raise
            if n <= 0:
                self.short_writes += 1
                return False
            del self.pending[:n]
        return True
