"""Host link transports and the factory that opens one from a link spec.

``open_transport(spec, ...)`` looks the spec's kind (:func:`protocol.linkkinds.link_kind`) up in
the host's registry (:data:`host.link.kinds.HOST_TRANSPORTS`): serial kinds ->
:class:`host.link.transports.serial.SerialLinkTransport`; CAN kinds ->
:func:`host.link.transports.can.open_can_transport` (python-can is imported only for CAN links).

The transport adapters are the one part of ``host.link`` written against asyncio's loop rather than
anyio (the session, supervisor, requests and waits are anyio; the background loops' task is
spawned in :mod:`host.link.background`, which says why). Why here: a transport has no task of its
own; the :class:`Transport` contract is callbacks (``connect(on_receive, on_lost)``), and the bytes
or frames are handled in the loop's readiness callback itself (``loop.add_reader`` /
``add_writer`` on the port's or bus's fd), with no task switch per wake-up. anyio's
``wait_readable`` would need a reader task per transport, spawned and cancelled across reconnects,
for the same effect. python-can's :class:`can.Notifier`, the receive path of buses without a file
descriptor (the virtual bus), takes an asyncio loop and hands frames over with
``call_soon_threadsafe``; pyserial's thread transport (ports without an fd) does the same. The link
therefore runs on anyio's asyncio backend (``anyio.run(..., backend="asyncio")``, as every host
command that opens a link does) or under ``asyncio.run``; never under trio.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from host.link.errors import LinkError
from host.link.transports.base import LossHandler, ReceiveHandler, Transport
from protocol.linkkinds import link_kind
from protocol.linkspec import LinkSpec, parse_link_spec

__all__ = ["LossHandler", "ReceiveHandler", "Transport", "open_transport"]


def open_transport(
    spec: LinkSpec | str | Callable[[], LinkSpec | str],
    *,
    baud: int = 115200,
    log_path: str | Path | None = None,
    force_thread: bool = False,
    servo_count: int | None = None,
    **options: Any,
) -> Transport:
    """A transport for ``spec`` (not yet connected: the session calls ``connect``).

    ``baud`` and ``force_thread`` apply to serial links; ``log_path`` is the frame log
    (its format is the transport's: JSON Lines for serial); ``servo_count`` is the robot's (its
    wire form, :meth:`Transport.set_servo_count`; None: not known yet). Further keyword ``options``
    go to the CAN transport. ``spec`` may be a callable: a serial transport then re-resolves
    its port on every ``connect`` (a board that came back on another pty), a CAN transport its spec. Raises :class:`protocol.linkspec.LinkSpecError` for a bad
    spec and :class:`LinkError` for a kind no transport serves.
    """
    resolve = spec if callable(spec) else None
    spec = parse_link_spec(spec() if callable(spec) else spec)
    from host.link.kinds import HOST_TRANSPORTS  # the registry imports this package's base

    kind = link_kind(spec)
    opener = HOST_TRANSPORTS.get(kind.name)
    if opener is None:
        raise LinkError(f"no transport for link kind {kind.name!r}")
    return opener(spec, resolve, baud=baud, log_path=log_path, force_thread=force_thread,
                  servo_count=servo_count, **options)
