"""The wire-time model of a serial line (sans-I/O: bytes and times in, bytes out; no clock of its own).

A pty ignores baud rates, so an emulated line that should behave like a UART of ``baud`` bit/s
delays every byte by its wire time: 10 bit times per byte (start + 8 data + stop, 8N1). Chunks
are serialised: a chunk pushed while the line is still busy starts when the previous one ends.
The caller passes the time (``now``, seconds on any monotonic clock) to every call; the model
only orders and releases bytes. Used by the emulated board's serial transport (both directions)
and by the C firmware launcher's relay between two ptys; the host keeps one for its own sends
(:attr:`host.link.client.BoardClient.tx_wire`) to know how long the line is busy.
"""

from __future__ import annotations

import argparse
from collections import deque

__all__ = ["BITS_PER_BYTE", "MAX_BAUD", "WireModel", "baud_arg"]

#: UART 8N1: start bit + 8 data bits + stop bit
BITS_PER_BYTE = 10

#: the highest ``--baud`` either end takes (bit/s): the fastest common USB UART bridges run at 12 Mbaud
#: (FTDI FT232H); far larger values reached pyserial's termios call and ended in an OverflowError traceback
MAX_BAUD = 12_000_000


def baud_arg(text: str) -> int:
    """argparse ``type=`` for ``--baud`` on both ends' command lines: a whole number of bit/s,
    1 .. :data:`MAX_BAUD` (``argparse.ArgumentTypeError`` otherwise)."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of bit/s, e.g. 115200, got {text!r}") from None
    if not 1 <= v <= MAX_BAUD:
        raise argparse.ArgumentTypeError(f"must be 1..{MAX_BAUD} bit/s, got {v}")
    return v


class WireModel:
    """Serialises bytes on a modelled UART: each chunk finishes ``10 * n / baud`` s after the previous.

    ``baud`` None (or 0): no model, every chunk is released at the time it was pushed.
    ``delimiter``: the byte that ends a frame (:data:`protocol.framing.FRAME_DELIMITER`), or None. With
    it a chunk is released frame by frame, each once its own last byte is through, as a UART delivers
    bytes one after another: of two frames read from a pty in one read, the first is there when its own
    bytes are, not when the second's are. Without it a chunk is released whole.
    ``free_at``: the time the line becomes idle; ``bytes_queued``: bytes pushed, not yet released.
    """

    def __init__(self, baud: int | None, delimiter: int | None = None) -> None:
        self.baud = baud or None  # bit/s, None: no model
        self.byte_time = BITS_PER_BYTE / baud if baud else 0.0
        self.delimiter = delimiter
        self.free_at = 0.0
        self.queue: deque[tuple[float, bytes]] = deque()
        self.bytes_queued = 0

    def wire_s(self, nbytes: int) -> float:
        """How long ``nbytes`` take on the line (s): ``10 * nbytes / baud`` (8N1); 0 without a model."""
        return nbytes * self.byte_time

    def occupy(self, now: float, nbytes: int) -> float:
        """``nbytes`` enter the line at ``now`` (s) without being kept; returns when their last byte is
        through (s). For a sender that only needs the line's timing (the host's model of its own UART)."""
        if self.byte_time:
            self.free_at = max(self.free_at, now) + self.wire_s(nbytes)
            return self.free_at
        return now

    def push(self, now: float, data: bytes) -> None:
        """``data`` enters the line at ``now`` (s); it is released once its last byte is through (with a
        ``delimiter``: each frame of it once that frame's last byte is through)."""
        start = 0
        if self.delimiter is not None and self.byte_time:
            while (end := data.find(self.delimiter, start) + 1) and end < len(data):
                self.queue.append((self.occupy(now, end - start), data[start:end]))
                start = end
        self.queue.append((self.occupy(now, len(data) - start), data[start:] if start else data))
        self.bytes_queued += len(data)

    def next_release(self) -> float | None:
        """When the next chunk is through (s), or None when nothing waits."""
        return self.queue[0][0] if self.queue else None

    def pop_ready(self, now: float) -> bytes:
        """Every byte through the line by ``now``, in order (b"" when none)."""
        out = bytearray()
        while self.queue and self.queue[0][0] <= now:
            out += self.queue.popleft()[1]
        self.bytes_queued -= len(out)
        return bytes(out)

    def busy_s(self, now: float) -> float:
        """Seconds of wire time already committed beyond ``now`` (0 without a model, never negative)."""
        return max(0.0, self.free_at - now) if self.byte_time else 0.0
