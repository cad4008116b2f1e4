"""Board link transports and the factory that opens one from a link spec.

``open_board_transport(spec, ...)`` dispatches on :attr:`protocol.linkspec.LinkSpec.kind`:
``"serial"`` -> :class:`firmware_sim.transports.serial.SerialBoardTransport` (``pty``
creates a pty pair); ``"can"`` -> :func:`firmware_sim.transports.can.open_can_board_transport`
(SocketCAN or virtual through python-can, or the SLCAN adapter on a pty).
"""

from __future__ import annotations

from typing import Any

from firmware_sim.transports.base import BoardTransport
from protocol.linkspec import LinkSpec, parse_link_spec

__all__ = ["BoardTransport", "open_board_transport"]


def open_board_transport(
    spec: LinkSpec | str,
    *,
    baud: int | None = None,
    log_path: str | None = None,
    servo_count: int | None = None,
    **options: Any,
) -> BoardTransport:
    """Open the board's end of ``spec``; ``baud`` models serial wire time; ``log_path`` is the frame log;
    ``servo_count`` is the robot's: its wire schema / CAN layout table (None: the defaults, for a
    robot of up to 16 servos on serial, :data:`protocol.can.layouts.DEFAULT_SERVO_COUNT` on CAN).

    Raises :class:`protocol.linkspec.LinkSpecError` for a bad spec, ``ValueError`` for a kind
    no transport serves, ``OSError`` / ``serial.SerialException`` when the port cannot be opened.
    """
    spec = parse_link_spec(spec)
    if spec.kind == "serial":
        from firmware_sim.transports.serial import SerialBoardTransport

        return SerialBoardTransport(spec.port, baud=baud, log_path=log_path, servo_count=servo_count)
    if spec.kind == "can":
        from firmware_sim.transports.can import open_can_board_transport  # python-can loads only for CAN links

        return open_can_board_transport(spec, log_path=log_path, servo_count=servo_count, **options)
    raise ValueError(f"no transport for link kind {spec.kind!r}")
