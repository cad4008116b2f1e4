"""The host's registry of link kinds: kind name (:mod:`protocol.linkkinds`) -> how the host opens its end.

One entry per kind; :func:`host.link.transports.open_transport` looks the spec's kind up here and
nowhere else decides by a spec's fields. A new kind is one :class:`protocol.linkkinds.LinkKind` plus
one entry here (and one in the board's ``firmware_sim.transports.kinds``). python-can is imported only
when a CAN kind is opened.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from host.link.errors import LinkError
from host.link.transports.base import Transport
from protocol.linkspec import LinkSpec, parse_link_spec

__all__ = ["HOST_TRANSPORTS", "Opener"]

#: ``opener(spec, resolve, *, baud, log_path, force_thread, servo_count, **options) -> Transport``;
#: ``resolve`` (or None) gives the spec anew on every connect (a board that came back elsewhere)
Opener = Callable[..., Transport]


def _board_created(spec: LinkSpec, resolve: Callable[[], LinkSpec | str] | None, **_: Any) -> Transport:
    raise LinkError("'pty' names a link the emulated board creates: start the board first "
                    "(ghostshell run --link pty does) and connect to the pty it announces")


def _serial(spec: LinkSpec, resolve: Callable[[], LinkSpec | str] | None, *, baud: int,
            log_path: str | Path | None, force_thread: bool, servo_count: int | None, **_: Any) -> Transport:
    from host.link.transports.serial import SerialLinkTransport

    port: str | Callable[[], str] = spec.port
    if resolve is not None:
        r = resolve
        port = lambda: parse_link_spec(r()).port  # noqa: E731
    return SerialLinkTransport(port, baud=baud, log_path=log_path, force_thread=force_thread,
                               servo_count=servo_count)


def _can(spec: LinkSpec, resolve: Callable[[], LinkSpec | str] | None, *, baud: int,
         log_path: str | Path | None, force_thread: bool, servo_count: int | None, **options: Any) -> Transport:
    from host.link.transports.can import open_can_transport  # python-can loads only for CAN links

    if resolve is not None:
        options.setdefault("resolve", resolve)
    return open_can_transport(spec, log_path=log_path, servo_count=servo_count, **options)


#: kind name -> opener (``pty`` is refused: only the emulated board creates it, the host connects to
#: the pty it announces; every CAN kind opens a python-can bus, ``bus=`` passes an open one)
HOST_TRANSPORTS: dict[str, Opener] = {
    "pty": _board_created,
    "serial": _serial,
    "slcan-pty": _can,
    "slcan": _can,
    "socketcan": _can,
    "virtual": _can,
    "can": _can,
}
