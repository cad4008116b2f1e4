"""Serve a :class:`firmware_sim.plant.bus.PlantBus` on a pty: the servo bus alone, for any client.

``python -m firmware_sim.plant [--protocol sts|dxl2] [--baud N] [--robot NAME] [--robots-dir DIR]
[--scene NAME] [--lockstep] [conditions...]`` (protocol, baud and model numbers default to the robot's
``hardware.toml``, :mod:`robots.hardware`) prints ``plant: servo bus on /dev/pts/N`` and answers
there until SIGTERM/SIGINT: a vendor SDK (``scservo_sdk``, ``dynamixel_sdk``), a servo tool or the C
firmware can drive the emulated servos. In lockstep every goal SYNC WRITE steps the world one control
period; in realtime it steps on the wall clock. The pty starts at ``--baud``; a client that sets
another line speed gets no answer (read from the pty's termios before each read). Conditions:
``--offset ID=STEPS``, ``--reverse ID``, ``--model ID=NUMBER``, ``--missing ID``, ``--duplicate ID``,
``--error ID=overload|overheat|voltage@SECONDS``, ``--corrupt P`` with ``--seed N``,
``--dead-servo ID@SECONDS`` (all repeatable but the last three; docs/reference/plant.md). ``--hand``: lines on
stdin move and hold the limp joints as a person's hand would (``shoulder_pan 30``, ``pose zero``,
``release all``; :mod:`firmware_sim.plant.hand`). :func:`serve` is the loop (tests run it in a thread with a
stop event).
"""

from __future__ import annotations

import argparse
import json
import select
import signal
import sys
import termios
import threading
import time
from collections.abc import Callable
from typing import TypeVar

from firmware_sim.plant.hand import HELP, Hand

from firmware_sim.plant.bus import PROTOCOLS, PlantBus
from firmware_sim.plant.conditions import Conditions, parse_error, parse_id, parse_id_int
from firmware_sim.plant.world import World
from firmware_sim.transports.ports import PtyPort

__all__ = ["line_speed", "main", "parser", "serve", "set_line_speed"]

T = TypeVar("T")

#: termios speed constant -> bits per second (Linux: B1000000 and friends included)
_SPEEDS: dict[int, int] = {getattr(termios, f"B{b}"): b for b in (
    9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600, 1000000, 1152000, 1500000,
    2000000, 2500000, 3000000, 3500000, 4000000) if hasattr(termios, f"B{b}")}
_CONSTANTS = {b: c for c, b in _SPEEDS.items()}


def line_speed(fd: int) -> int | None:
    """The line speed (bit/s) the pty's client set: the master's termios reflect the slave's
    (Linux). None when it is not a known speed constant (e.g. a custom BOTHER rate)."""
    try:
        return _SPEEDS.get(termios.tcgetattr(fd)[5])
    except termios.error:
        return None


def set_line_speed(fd: int, baud: int) -> None:
    """Set the pty's line speed (the speed a client that never sets one is at)."""
    const = _CONSTANTS.get(baud)
    if const is None:
        return
    attrs = termios.tcgetattr(fd)
    attrs[4] = attrs[5] = const
    termios.tcsetattr(fd, termios.TCSANOW, attrs)


def serve(plant: PlantBus, port: PtyPort, stop: threading.Event, hand: Hand | None = None) -> None:
    """Answer on ``port`` until ``stop`` is set; ``hand``: its queued commands are applied every turn (at most
    50 ms apart)."""
    out = bytearray()
    while not stop.is_set():
        if hand is not None:
            hand.apply()
        now = time.monotonic()
        timeout = 0.05
        for t in (plant.next_step_time(), plant.next_release()):
            if t is not None:
                timeout = min(timeout, max(0.0, t - now))
        r, _, _ = select.select([port.master], [port.master] if out else [], [], timeout)
        now = time.monotonic()
        if r:
            plant.line_baud = line_speed(port.master)
            data = port.read()
            if data:
                out += plant.feed(data, now)
        plant.step_due(now)
        out += plant.ready(now)
        if out:
            del out[: port.write(bytes(out))]


#: the widest ``--baud`` (bit/s), as ``ghostshell run --baud``
MAX_BAUD = 12_000_000
#: a model number is a 2-byte register
MAX_MODEL = 0xFFFF


def _ranges(ids: list[int]) -> str:
    """``[1, 2, 3, 5]`` -> ``"1..3, 5"``."""
    runs: list[list[int]] = []
    for i in sorted(set(ids)):
        if runs and runs[-1][-1] == i - 1:
            runs[-1][-1] = i
        else:
            runs.append([i, i])
    return ", ".join(str(a) if a == b else f"{a}..{b}" for a, b in runs)


def refusal(args: argparse.Namespace, robot_name: str, servo_ids: list[int]) -> str | None:
    """The first option in ``args`` that makes no sense for a robot with ``servo_ids``, as one line naming the
    option and its valid range, or None. ``--missing``, ``--duplicate`` and ``--dead-servo`` name a device:
    a servo, the IMU (0xF0) or the probe (0xF1); the rest name a servo."""
    from firmware_sim.plant.devices import IMU_ID, PROBE_ID

    servos = set(servo_ids)
    servo_range = f"{robot_name}'s servo ids are {_ranges(servo_ids)}"
    device_range = f"{servo_range}, the IMU 0x{IMU_ID:X}, the probe 0x{PROBE_ID:X}"
    if args.baud is not None and not 1 <= args.baud <= MAX_BAUD:
        return f"--baud {args.baud}: the baud rate must be 1..{MAX_BAUD} bit/s"
    per_servo: list[tuple[str, int, str]] = [
        *(("--offset", sid, f"{sid}={v}") for sid, v in args.offset),
        *(("--reverse", sid, str(sid)) for sid in args.reverse),
        *(("--model", sid, f"{sid}={v}") for sid, v in args.model),
        *(("--error", e.id, f"{e.id}=...") for e in args.error)]
    for option, sid, text in per_servo:
        if sid not in servos:
            return f"{option} {text}: {sid} is not a servo; {servo_range}"
    for option, sid in [*(("--missing", i) for i in args.missing), *(("--duplicate", i) for i in args.duplicate),
                        *(("--dead-servo", i) for i, _ in args.dead_servo)]:
        if sid not in servos and sid not in (IMU_ID, PROBE_ID):
            return f"{option} {sid}: no such device on the bus; {device_range}"
    for sid, v in args.model:
        if not 0 <= v <= MAX_MODEL:
            return f"--model {sid}={v}: a model number must be 0..{MAX_MODEL}"
    for sid, at in args.dead_servo:
        if not at >= 0:
            return f"--dead-servo {sid}@{at:g}: the time must be 0 or more world seconds"
    return None


def _conditions(args: argparse.Namespace, hw_models: dict[int, int]) -> Conditions:
    return Conditions(
        offsets=dict(args.offset), reversed=frozenset(args.reverse), models={**hw_models, **dict(args.model)},
        missing=frozenset(args.missing), duplicate=frozenset(args.duplicate), errors=tuple(args.error),
        corrupt=args.corrupt, seed=args.seed)


def _arg(fn: Callable[[str], T]) -> Callable[[str], T]:
    """``fn`` for argparse: its ValueError's message becomes the command line's error."""
    def parse(text: str) -> T:
        try:
            return fn(text)
        except ValueError as e:
            raise argparse.ArgumentTypeError(str(e)) from None
    parse.__name__ = fn.__name__
    return parse


def _dead(text: str) -> tuple[int, float]:
    sid, sep, at = text.partition("@")
    if not sep:
        raise ValueError(f"expected ID@SECONDS, got {text!r}")
    try:
        return parse_id(sid), float(at)
    except ValueError as e:
        raise ValueError(f"expected ID@SECONDS, got {text!r} ({e})") from None


def parser() -> argparse.ArgumentParser:
    from robots.registry import DEFAULT_ROBOT

    p = argparse.ArgumentParser(
        prog="python -m firmware_sim.plant",
        description="Serve a robot's emulated servo bus on a pty, for any client (a vendor SDK, a servo tool, "
                    "the C firmware): prints 'plant: servo bus on /dev/pts/N' and answers there until SIGTERM "
                    "or SIGINT, then prints its bus summary on stderr (exit 0; a bad option exits 2).",
        epilog="Ids: the robot's servos at their servo-table ids, the IMU at 0xF0, the ground-truth probe at 0xF1 "
               "(emulator only). Times in --error and --dead-servo are the plant's world time from its start. "
               "docs/reference/plant.md has the register maps.")
    p.add_argument("--robot", default=None, metavar="NAME",
                   help=f"the robot whose servos answer: a name (ghostshell robots list) or a robot folder "
                        f"(default {DEFAULT_ROBOT})")
    p.add_argument("--robots-dir", default=None, metavar="DIR", help="search this folder for --robot first")
    p.add_argument("--scene", default=None, metavar="NAME",
                   help="objects in the world: one of the robot's scenes (default: the robot's default scene)")
    p.add_argument("--protocol", choices=PROTOCOLS, default=None,
                   help="the servos' wire protocol (default: the robot's hardware.toml, else sts)")
    p.add_argument("--baud", type=int, default=None, metavar="N",
                   help="the servos' baud rate, bit/s (default: the robot's hardware.toml, else 1000000)")
    p.add_argument("--lockstep", action="store_true",
                   help="step the world one control period per SYNC WRITE that covers the goal position (a plain "
                        "WRITE sets a goal but moves nothing); default: step on the wall clock")
    p.add_argument("--offset", type=_arg(parse_id_int), action="append", default=[], metavar="ID=STEPS",
                   help="servo ID reads STEPS more than a calibrated one")
    p.add_argument("--reverse", type=_arg(parse_id), action="append", default=[], metavar="ID",
                   help="servo ID turns the other way")
    p.add_argument("--model", type=_arg(parse_id_int), action="append", default=[], metavar="ID=NUMBER",
                   help="servo ID reports model NUMBER")
    p.add_argument("--missing", type=_arg(parse_id), action="append", default=[], metavar="ID", help="ID never answers")
    p.add_argument("--duplicate", type=_arg(parse_id), action="append", default=[], metavar="ID",
                   help="two devices answer ID (their replies collide)")
    p.add_argument("--error", type=_arg(parse_error), action="append", default=[], metavar="ID=KIND@SECONDS",
                   help="servo ID reports overload, overheat or voltage from world time SECONDS")
    p.add_argument("--corrupt", type=float, default=0.0, metavar="P",
                   help="probability that a status packet's checksum is broken")
    p.add_argument("--seed", type=int, default=0, metavar="N", help="seed of --corrupt's random draws (default 0)")
    p.add_argument("--dead-servo", type=_arg(_dead), action="append", default=[], metavar="ID@SECONDS",
                   help="device ID stops answering at world time SECONDS")
    p.add_argument("--hand", action="store_true",
                   help="read lines on stdin that hold limp joints at an angle, as a hand: 'shoulder_pan 30' (degrees), "
                        "'pose zero', 'release NAME|all', 'show'")
    return p


def main(argv: list[str] | None = None) -> int:
    from robots.description import RobotDataError
    from robots.hardware import DEFAULT_BAUD, HARDWARE_FILE, load_hardware
    from robots.registry import DEFAULT_ROBOT, load_robot

    args = parser().parse_args(argv)
    try:
        robot = load_robot(args.robot or DEFAULT_ROBOT, args.robots_dir)
        if args.scene is not None and args.scene not in robot.scenes:
            raise ValueError(f"--scene {args.scene}: {robot.name} has no such scene; scenes: {', '.join(robot.scenes)}")
        why = refusal(args, robot.name, [s.id for s in robot.servos])
        if why is not None:
            raise ValueError(why)
        hw = load_hardware(robot.root, list(robot.servos))
        protocol = args.protocol or hw.protocol
        # the robot's own servo models when the file describes this protocol's bus
        same = (robot.root / HARDWARE_FILE).is_file() and hw.protocol == protocol
        hw_models = {s.id: hw.model_of(s) for s in robot.servos} if same else {}
        baud = args.baud or (hw.baud if same else DEFAULT_BAUD[protocol])
        world = World(robot, scene=args.scene, conditions=_conditions(args, hw_models))
        plant = PlantBus(world, lockstep=args.lockstep, baud=baud, protocol=protocol)
    except (RobotDataError, ValueError) as e:
        print(f"plant: {e}", file=sys.stderr)
        return 2
    for sid, at in args.dead_servo:
        plant.kill(sid, int(at * 1e6))
    port = PtyPort()
    set_line_speed(port.slave, baud)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    print(f"plant: servo bus on {port.name}", flush=True)
    hand = None
    if args.hand:
        hand = Hand(plant.world)
        print(HELP, flush=True)
        threading.Thread(target=hand.read, args=(sys.stdin,), name="plant-hand", daemon=True).start()
    try:
        serve(plant, port, stop, hand)
    finally:
        print(f"plant: {plant.stats.line(plant.world.period_us)}", file=sys.stderr, flush=True)
        if not plant.lockstep:
            print(f"plant: realtime lateness {json.dumps(plant.lateness.as_dict())}", file=sys.stderr, flush=True)
        port.close()
    return 0
