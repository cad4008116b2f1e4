"""Board link transports and the factory that opens one from a link spec.

``open_board_transport(spec, ...)`` dispatches on :attr:`protocol.linkspec.LinkSpec.kind`:
``"serial"`` -> :class:`firmware_sim.transports.serial.SerialBoardTransport` (``pty``
creates a pty pair); ``"can"`` -> ``firmware_sim.transports.can.open_can_board_transport(spec, *, log_path, **options)``
(the hook for the CAN transport: while that module does not exist, a CAN spec raises
``ValueError("CAN transport not available ...")``).
"""

from __future__ import annotations

import importlib
from typing import Any

from firmware_sim.transports.base import BoardTransport
from protocol.linkspec import LinkSpec, parse_link_spec

__all__ = ["CAN_MODULE", "BoardTransport", "open_board_transport"]

#: the module providing ``open_can_board_transport(spec, *, log_path, **options) -> BoardTransport``
CAN_MODULE = "firmware_sim.transports.can"


def open_board_transport(
    spec: LinkSpec | str,
    *,
    baud: int | None = None,
    log_path: str | None = None,
    **options: Any,
) -> BoardTransport:
    """Open the board's end of ``spec``; ``baud`` models serial wire time; ``log_path`` is the frame log.

    Raises :class:`protocol.linkspec.LinkSpecError` for a bad spec, ``ValueError`` for a kind
    no transport serves, ``OSError`` / ``serial.SerialException`` when the port cannot be opened.
    """
    spec = parse_link_spec(spec)
    if spec.kind == "serial":
        from firmware_sim.transports.serial import SerialBoardTransport

        return SerialBoardTransport(spec.port, baud=baud, log_path=log_path)
    if spec.kind == "can":
        try:
            mod = importlib.import_module(CAN_MODULE)
        except ModuleNotFoundError as e:
            if e.name != CAN_MODULE:
                raise
            raise ValueError(f"CAN transport not available: cannot serve {spec}") from None
        transport: BoardTransport = mod.open_can_board_transport(spec, log_path=log_path, **options)
        return transport
    raise ValueError(f"no transport for link kind {spec.kind!r}")
