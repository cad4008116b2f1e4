"""python-can's ``can.Message`` <-> :class:`protocol.can.frame.CanFrame`, for both ends' CAN transports.

The protocol's CAN code works on plain :class:`CanFrame` values; the transports (host and board) talk
to python-can buses. These two conversions are the only place the two meet (and the frame logs,
:mod:`protocol.logfile`); python-can is imported here and nowhere else in ``protocol/``.
"""

from __future__ import annotations

import time

import can

from protocol.can.frame import CanFrame

__all__ = ["from_can_message", "to_can_message"]


def to_can_message(frame: CanFrame, channel: str | None = None, is_rx: bool = False,
                   timestamp: float | None = None) -> can.Message:
    """A python-can message for ``frame`` (``timestamp`` None: now, wall clock; ``dlc`` = the data length)."""
    return can.Message(
        timestamp=time.time() if timestamp is None else timestamp,
        arbitration_id=frame.arbitration_id,
        data=frame.data,
        is_fd=frame.is_fd,
        is_extended_id=frame.is_extended_id,
        is_remote_frame=frame.is_remote,
        channel=channel,
        is_rx=is_rx,
        dlc=len(frame.data),
    )


def from_can_message(msg: can.Message) -> CanFrame:
    """The frame a python-can message carries, with its arrival ``timestamp`` (error frames are the caller's to filter)."""
    return CanFrame(
        int(msg.arbitration_id),
        bytes(msg.data or b""),
        is_fd=bool(msg.is_fd),
        is_extended_id=bool(msg.is_extended_id),
        is_remote=bool(msg.is_remote_frame),
        timestamp=float(msg.timestamp) if msg.timestamp else None,
    )
