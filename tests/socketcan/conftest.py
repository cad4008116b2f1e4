"""SocketCAN tests: they need a real ``vcan0`` (and ``vcan1``) interface.

Where this kernel has ``vcan0`` up they run in the normal session. Elsewhere they are not
collected here at all: ``tests/uml/test_socketcan_in_uml.py`` boots User-Mode Linux once and runs
this directory inside it (see ``support/uml.py``), so a host session neither runs them twice nor
reports them as skipped.
"""

from __future__ import annotations

from collections.abc import Iterator

import can
import pytest

from support.uml import native_vcan

if not native_vcan("vcan0"):
    collect_ignore_glob = ["test_*.py"]

CHANNEL = "vcan0"
#: A second interface for tests that change qdiscs (tc) so vcan0 stays a plain bus.
SCRATCH_CHANNEL = "vcan1"


@pytest.fixture
def open_bus() -> Iterator[object]:
    """A factory ``open_bus(channel="vcan0", fd=False, **kw) -> can.BusABC``; buses shut down after the test."""
    buses: list[can.BusABC] = []

    def factory(channel: str = CHANNEL, fd: bool = False, **kwargs: object) -> can.BusABC:
        bus = can.Bus(interface="socketcan", channel=channel, fd=fd, **kwargs)
        buses.append(bus)
        return bus

    yield factory
    for bus in buses:
        bus.shutdown()
