"""A plant serving on a real pty from a thread of the test process, for a vendor SDK to drive.

The SDKs poll their port in a busy loop holding the GIL, so the plant's thread gets its turns sooner
(``sys.setswitchinterval``) and the SDK the answer time a USB adapter's latency timer would give (its
``LATENCY_TIMER``, 16 ms by default, is the knob the SDK exposes). The pty starts at the plant's baud.
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import pytest

from firmware_sim.plant.bus import PlantBus
from firmware_sim.plant.conditions import Conditions
from firmware_sim.plant.server import serve, set_line_speed
from firmware_sim.plant.world import World
from firmware_sim.transports.ports import PtyPort
from robots.registry import load_robot

ROBOT = load_robot("coco")
STEP = ROBOT.servos.model.resolution


@dataclass
class Served:
    world: World
    plant: PlantBus
    port: PtyPort


@contextmanager
def served(monkeypatch: pytest.MonkeyPatch, latency_module: object, *, protocol: str, baud: int,
           conditions: Conditions | None = None, lockstep: bool = True, robot: str = "coco") -> Iterator[Served]:
    """Run a plant for ``protocol`` at ``baud`` on a pty until the block ends."""
    old = sys.getswitchinterval()
    sys.setswitchinterval(0.0002)
    monkeypatch.setattr(latency_module, "LATENCY_TIMER", 100)
    world = World(ROBOT if robot == "coco" else load_robot(robot), conditions=conditions)
    plant = PlantBus(world, lockstep=lockstep, baud=baud, protocol=protocol)
    port = PtyPort()
    set_line_speed(port.slave, baud)
    stop = threading.Event()
    th = threading.Thread(target=serve, args=(plant, port, stop), daemon=True)
    th.start()
    try:
        yield Served(world, plant, port)
    finally:
        stop.set()
        th.join(5)
        port.close()
        sys.setswitchinterval(old)
