"""Serve a :class:`firmware_sim.plant.bus.PlantBus` on a pty: the servo bus alone, for any client.

``python -m firmware_sim.plant [--robot NAME] [--scene NAME] [--lockstep]`` prints
``plant: servo bus on /dev/pts/N`` and answers there until SIGTERM/SIGINT: the vendor SDK
(``scservo_sdk``), a servo tool or the C firmware can drive the emulated servos. In lockstep every
goal SYNC WRITE steps the world one control period; in realtime it steps on the wall clock.
:func:`serve` is the loop (tests run it in a thread with a stop event).
"""

from __future__ import annotations

import argparse
import json
import select
import signal
import sys
import threading
import time

from firmware_sim.plant.bus import PlantBus
from firmware_sim.plant.world import World
from firmware_sim.transports.ports import PtyPort

__all__ = ["main", "serve"]


def serve(plant: PlantBus, port: PtyPort, stop: threading.Event) -> None:
    """Answer on ``port`` until ``stop`` is set."""
    out = bytearray()
    while not stop.is_set():
        now = time.monotonic()
        timeout = 0.05
        for t in (plant.next_step_time(), plant.next_release()):
            if t is not None:
                timeout = min(timeout, max(0.0, t - now))
        r, _, _ = select.select([port.master], [port.master] if out else [], [], timeout)
        now = time.monotonic()
        if r:
            data = port.read()
            if data:
                out += plant.feed(data, now)
        plant.step_due(now)
        out += plant.ready(now)
        if out:
            del out[: port.write(bytes(out))]


def main(argv: list[str] | None = None) -> int:
    from robots.description import RobotDataError
    from robots.registry import DEFAULT_ROBOT, load_robot

    p = argparse.ArgumentParser(prog="python -m firmware_sim.plant", description=__doc__.splitlines()[0])
    p.add_argument("--robot", default=DEFAULT_ROBOT)
    p.add_argument("--robots-dir", default=None)
    p.add_argument("--scene", default=None)
    p.add_argument("--lockstep", action="store_true", help="step the world once per goal SYNC WRITE")
    args = p.parse_args(argv)
    try:
        robot = load_robot(args.robot, args.robots_dir)
    except RobotDataError as e:
        print(f"plant: {e}", file=sys.stderr)
        return 2
    plant = PlantBus(World(robot, scene=args.scene), lockstep=args.lockstep)
    port = PtyPort()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    print(f"plant: servo bus on {port.name}", flush=True)
    try:
        serve(plant, port, stop)
    finally:
        print(f"plant: {plant.stats.line(plant.world.period_us)}", file=sys.stderr, flush=True)
        if not plant.lockstep:
            print(f"plant: realtime lateness {json.dumps(plant.lateness.as_dict())}", file=sys.stderr, flush=True)
        port.close()
    return 0
