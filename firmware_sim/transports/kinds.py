"""The board's registry of link kinds: kind name (:mod:`protocol.linkkinds`) -> how the board opens its end.

One entry per kind the board serves; :func:`firmware_sim.transports.open_board_transport` looks the
spec's kind up here and nowhere else decides by a spec's fields. A new kind is one
:class:`protocol.linkkinds.LinkKind` plus one entry here (and one in the host's ``host.link.kinds``).
python-can is imported only when a CAN kind is opened.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from firmware_sim.transports.base import BoardTransport
from protocol.linkspec import LinkSpec

__all__ = ["BOARD_TRANSPORTS", "Opener"]

#: ``opener(spec, *, baud, log_path, servo_count, **options) -> BoardTransport``
Opener = Callable[..., BoardTransport]


def _serial(spec: LinkSpec, *, baud: int | None, log_path: str | None, servo_count: int | None,
            **options: Any) -> BoardTransport:
    from firmware_sim.transports.serial import SerialBoardTransport

    return SerialBoardTransport(spec.port, baud=baud, log_path=log_path, servo_count=servo_count)


def _slcan_pty(spec: LinkSpec, *, baud: int | None, log_path: str | None, servo_count: int | None,
               **options: Any) -> BoardTransport:
    from firmware_sim.transports.can import SlcanBoardTransport

    return SlcanBoardTransport(spec, log_path, servo_count)


def _bus(spec: LinkSpec, *, baud: int | None, log_path: str | None, servo_count: int | None,
         **options: Any) -> BoardTransport:
    from firmware_sim.transports.can import BusBoardTransport

    return BusBoardTransport(spec, log_path, bus=options.get("bus"), servo_count=servo_count)


#: kind name -> opener (``pty`` creates a pty pair; ``slcan-pty`` is the board as an SLCAN adapter on a new
#: pty; the other CAN kinds open a python-can bus, ``bus=`` passes an open one)
BOARD_TRANSPORTS: dict[str, Opener] = {
    "pty": _serial,
    "serial": _serial,
    "slcan-pty": _slcan_pty,
    "slcan": _bus,
    "socketcan": _bus,
    "virtual": _bus,
    "can": _bus,
}
