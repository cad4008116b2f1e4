"""Host link transports and the factory that opens one from a link spec.

``open_transport(spec, ...)`` dispatches on :attr:`protocol.linkspec.LinkSpec.kind`:
``"serial"`` -> :class:`host.link.transports.serial.SerialLinkTransport`;
``"can"`` -> :func:`host.link.transports.can.open_can_transport` (python-can is imported
only for CAN links).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from host.link.errors import LinkError
from host.link.transports.base import LossHandler, ReceiveHandler, Transport
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
    if spec.kind == "serial":
        if spec.is_pty:
            raise LinkError("'pty' names a link the emulated board creates: start the board first "
                            "(ghostshell run --link pty does) and connect to the pty it announces")
        from host.link.transports.serial import SerialLinkTransport

        port: str | Callable[[], str] = spec.port
        if resolve is not None:
            r = resolve
            port = lambda: parse_link_spec(r()).port  # noqa: E731
        return SerialLinkTransport(port, baud=baud, log_path=log_path, force_thread=force_thread,
                                   servo_count=servo_count)
    if spec.kind == "can":
        from host.link.transports.can import open_can_transport  # python-can loads only for CAN links

        if resolve is not None:
            options.setdefault("resolve", resolve)
        return open_can_transport(spec, log_path=log_path, servo_count=servo_count, **options)
    raise LinkError(f"no transport for link kind {spec.kind!r}")
