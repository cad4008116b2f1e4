"""Board link transports and the factory that opens one from a link spec.

``open_board_transport(spec, ...)`` looks the spec's kind (:func:`protocol.linkkinds.link_kind`) up
in the board's registry (:data:`firmware_sim.transports.kinds.BOARD_TRANSPORTS`): serial kinds ->
:class:`firmware_sim.transports.serial.SerialBoardTransport` (``pty`` creates a pty pair); CAN kinds ->
:class:`firmware_sim.transports.can.SlcanBoardTransport` (``can:slcan:pty``) or
:class:`~firmware_sim.transports.can.BusBoardTransport` (SocketCAN, virtual, any python-can bus).
"""

from __future__ import annotations

from typing import Any

from firmware_sim.transports.base import BoardTransport
from firmware_sim.transports.kinds import BOARD_TRANSPORTS
from protocol.linkkinds import link_kind
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
    """Open the board's end of ``spec``; ``baud`` models serial wire time; ``log_path`` is the frame log
    (its format by suffix, :mod:`protocol.logfile`); ``servo_count`` is the robot's: its wire schema / CAN
    layout table (None: the defaults, for a robot of up to 16 servos on serial,
    :data:`protocol.can.layouts.DEFAULT_SERVO_COUNT` on CAN). ``options`` go to the kind's opener
    (``bus=``: an open python-can bus).

    Raises :class:`protocol.linkspec.LinkSpecError` for a bad spec, ``ValueError`` for a kind
    no transport serves, ``OSError`` / ``serial.SerialException`` / python-can's errors when the
    port or bus cannot be opened.
    """
    spec = parse_link_spec(spec)
    kind = link_kind(spec)
    opener = BOARD_TRANSPORTS.get(kind.name)
    if opener is None:
        raise ValueError(f"no board transport for link kind {kind.name!r}")
    return opener(spec, baud=baud, log_path=log_path, servo_count=servo_count, **options)
