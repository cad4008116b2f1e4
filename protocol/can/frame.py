"""A CAN frame as plain data (no python-can import: ``protocol`` stays pure)."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["CLASSIC_MAX_DATA", "FD_MAX_DATA", "FD_LENGTHS", "CanFrame", "fd_length"]

CLASSIC_MAX_DATA = 8
FD_MAX_DATA = 64
#: Data lengths a CAN FD frame can have (DLC 0..15 -> these byte counts, ISO 11898-1:2015).
FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


def fd_length(n: int) -> int:
    """Smallest CAN FD data length >= ``n`` (``ValueError`` above 64)."""
    for size in FD_LENGTHS:
        if size >= n:
            return size
    raise ValueError(f"{n} bytes do not fit a CAN FD frame (max {FD_MAX_DATA})")


@dataclass(frozen=True)
class CanFrame:
    """One CAN frame: 11-bit (or 29-bit) ``arbitration_id``, ``data`` (0..8 bytes, FD 0..64).

    ``is_remote`` and ``is_extended_id`` exist so a receiver can see (and reject) whatever a bus
    delivers; the protocol itself only sends standard data frames. ``timestamp`` is when a received
    frame arrived (s, ``time.time()``'s clock, python-can's ``Message.timestamp``: the kernel's for
    SocketCAN), None when unknown; it takes no part in equality or hashing.
    """

    arbitration_id: int
    data: bytes = field(default=b"")
    is_fd: bool = False
    is_extended_id: bool = False
    is_remote: bool = False
    timestamp: float | None = field(default=None, compare=False)
