"""Fault injection on the board's serial link, both directions (``python -m firmware_sim --faults SPEC``).

:class:`FaultyWire` wraps a :class:`protocol.wiremodel.WireModel`: bytes the wire model
releases are split into frames at the 0x00 delimiter (the wire unit of the serial protocol) and
each frame goes through a seeded :class:`protocol.faults.FaultInjector` (drop, bit flip, duplicate,
reorder, truncate, delay, cut). Installed on both the receive and the transmit wire of a
:class:`SerialBoardTransport`, it covers host -> board and board -> host with one process and two
independent injectors (``rx`` and ``tx``, seeded from ``--fault-seed``). Times are the wire model's
``time.monotonic()`` seconds; ``cut=START+LEN`` counts from the first frame on each direction.

On CAN (:class:`firmware_sim.transports.can.CanBoardTransport`, SLCAN on a pty or any python-can
bus) the wire unit is one CAN frame: the ``rx`` injector sits between the frames read from the bus
and the decoder/ISO-TP layer, the ``tx`` one between the priority queue and the bus write; corrupt
flips a bit of the data field, truncate shortens the DLC, the others act per frame. The frame logs
show what the board sent (before ``tx`` faults) and what it received (after ``rx`` faults).
"""

from __future__ import annotations

import json
from typing import Any

from firmware_sim.transports.base import BoardTransport
from protocol.can.frame import CanFrame
from protocol.faults import FaultInjector, FaultSpec

__all__ = ["FaultyWire", "install_faults"]


class FaultyWire:
    """A :class:`WireModel` look-alike whose released frames pass a fault injector first."""

    def __init__(self, inner: Any, injector: FaultInjector[bytes]) -> None:
        self.inner = inner
        self.injector = injector
        self._partial = bytearray()

    @property
    def bytes_queued(self) -> int:
        return int(self.inner.bytes_queued) + len(self._partial)

    def busy_s(self, now: float) -> float:
        """Seconds until the wrapped line is idle (:meth:`WireModel.busy_s`); faults do not change it."""
        return float(self.inner.busy_s(now))

    def push(self, now: float, data: bytes) -> None:
        self.inner.push(now, data)

    def next_release(self) -> float | None:
        times = [t for t in (self.inner.next_release(), self.injector.next_due()) if t is not None]
        return min(times) if times else None

    def pop_ready(self, now: float) -> bytes:
        self._partial += self.inner.pop_ready(now)
        while True:
            end = self._partial.find(0)
            if end < 0:
                break
            self.injector.push(bytes(self._partial[: end + 1]), now)
            del self._partial[: end + 1]
        return b"".join(self.injector.pop_due(now))


def install_faults(link: BoardTransport, spec: FaultSpec, seed: int) -> list[FaultInjector[Any]]:
    """Wrap ``link``'s receive and transmit paths; returns the (rx, tx) injectors.

    Raises ``ValueError`` for a transport that is neither serial (a wire model) nor CAN.
    """
    from firmware_sim.transports.can import CanBoardTransport

    if isinstance(link, CanBoardTransport):
        crx: FaultInjector[CanFrame] = FaultInjector(spec, seed, "host->board")
        ctx: FaultInjector[CanFrame] = FaultInjector(spec, seed, "board->host")
        link.rx_faults, link.tx_faults = crx, ctx
        return [crx, ctx]
    if not (hasattr(link, "rx_wire") and hasattr(link, "tx_wire")):
        raise ValueError(f"--faults needs a serial or CAN link (not {type(link).__name__})")
    rx: FaultInjector[bytes] = FaultInjector(spec, seed, "host->board")
    tx: FaultInjector[bytes] = FaultInjector(spec, seed, "board->host")
    link.rx_wire = FaultyWire(link.rx_wire, rx)  # type: ignore[attr-defined]
    link.tx_wire = FaultyWire(link.tx_wire, tx)  # type: ignore[attr-defined]
    return [rx, tx]


def report_line(spec: FaultSpec, seed: int, injectors: list[FaultInjector[Any]], board: Any) -> str:
    """The ``board: faults {...}`` stderr line the host's runner copies into ``summary.json``."""
    detected = {"link_errors": int(board.link_errors), "late_frames": int(board.late_count),
                "dropped_frames": int(board.dropped_count), "watchdog_trips": int(board.safety.watchdog_trips),
                "seq_gaps": int(board.rx_gaps.lost)}
    return "board: faults " + json.dumps({"spec": str(spec), "seed": seed,
                                          "injected": [i.summary() for i in injectors],
                                          "board_detected": detected})
