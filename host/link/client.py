"""Compatibility name: :class:`BoardClient` lives in :mod:`host.link.session`."""

from host.link.session import (
    ALL_SERVOS,
    FAULT_BITS,
    BoardClient,
    FaultEvent,
    LinkStats,
    LinkTarget,
    PortSpec,
    host_now_us,
)

__all__ = ["ALL_SERVOS", "FAULT_BITS", "BoardClient", "FaultEvent", "LinkStats", "LinkTarget", "PortSpec", "host_now_us"]
