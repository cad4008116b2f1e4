"""``ghostshell robots calibrate NAME --servo-bus PORT[:BAUD]``: record a real robot's servo offsets,
directions and ranges by hand and write them to the robot package's ``calibration.toml``.

The procedure is :mod:`host.calibration.procedure` (after LeRobot's for SO-100/Koch arms): every servo
limp, the reference pose (the servo table's neutral), each joint a little towards positive, every joint
through its range. The bus is opened with the vendor SDK (:mod:`host.calibration.bus`), the protocol
and baud from the package's ``hardware.toml`` unless ``--bus-protocol`` / ``PORT:BAUD`` say otherwise.

Where it writes: ``calibration.toml`` belongs to one physical robot, so it goes into a user robot
package (``--robots-dir DIR``, ``$GHOSTSHELL_ROBOTS`` or the user robot folder) that is writable. A
built-in package is shared by every user of the installation and replaced on upgrade: calibrating
one is refused before the bus is opened, with the command that copies it into the user robot folder
(the copy, same name, is then found first). Nothing is written unless the whole procedure succeeds.

Exit status: 0 written; 2 bad input (arguments, a built-in or read-only package, a port that cannot be
opened, a servo missing or of the wrong model, a direction or range the checks refuse: one line
naming servo id and name); 1 the bus failed during the procedure or input ended; 130 Ctrl-C. Torque is
left off in every case.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from host.commands.errors import print_error
from robots.description import RobotDataError
from robots.registry import robots_dir_arg

if TYPE_CHECKING:
    from host.calibration.bus import ServoBus

__all__ = ["DESCRIPTION", "HELP", "configure", "main", "run"]

HELP = "record a real robot's servo offsets, directions and ranges into its calibration.toml"
DESCRIPTION = ("Record each servo's offset, direction and range by hand (torque off: move the joints yourself) "
               "and write them to the robot package's calibration.toml. The robot must be a user robot package "
               "(--robots-dir, $GHOSTSHELL_ROBOTS or the user robot folder), not a built-in one.")
COMMAND = "robots"


def _servo_bus(text: str) -> tuple[str, int | None]:
    from host.calibration.bus import parse_servo_bus

    try:
        return parse_servo_bus(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", metavar="NAME", help="a robot name or a robot folder (a user robot package)")
    parser.add_argument("--servo-bus", required=True, metavar="PORT[:BAUD]", type=_servo_bus,
                        help="the servos' serial port (e.g. /dev/ttyUSB0:1000000); BAUD default from hardware.toml")
    parser.add_argument("--bus-protocol", choices=("sts", "dxl2"), default=None,
                        help="sts (Feetech STS) or dxl2 (Dynamixel Protocol 2.0); default from hardware.toml (sts)")
    parser.add_argument("--robots-dir", default=None, metavar="DIR", type=robots_dir_arg,
                        help="a folder of robots searched first")


def _fail(message: str, status: int = 2) -> int:
    print_error(COMMAND, message)
    return status


def run(args: argparse.Namespace, *, ask: Callable[[str], str] | None = None, say: Callable[[str], None] = print,
        live: Callable[[Sequence[int], Sequence[int], Sequence[int]], None] | None = None) -> int:
    """The command with injectable input (``ask(prompt) -> line``, default :func:`input`), output and live
    range display (default: a table redrawn in place when stdout is a terminal)."""
    from host.calibration.bus import BusError, ServoBus
    from host.calibration.procedure import CalibrationError, calibrate, coverage_notes, live_table, table
    from robots.hardware import CALIBRATION_FILE, DEFAULT_BAUD, DEFAULT_MODEL, HARDWARE_FILE, Hardware, load_hardware
    from robots.hardware import save_calibration
    from robots.loader import load_robot_dir
    from robots.registry import find_robot, new_robots_dir

    try:
        folder, builtin = find_robot(args.name, args.robots_dir)
    except RobotDataError as e:
        return _fail(str(e))
    if builtin:
        copy = shlex.join(["cp", "-r", str(folder), str(new_robots_dir(args.robots_dir)) + os.sep])
        return _fail(f"{args.name} is a built-in robot ({folder}), shared and replaced on upgrade: calibrate your own "
                     f"copy of it, found first under the same name: {copy}")
    target = folder / CALIBRATION_FILE
    if not os.access(folder, os.W_OK) or (target.exists() and not os.access(target, os.W_OK)):
        return _fail(f"{target}: not writable (calibration.toml is written into the robot's folder)")
    try:
        robot = load_robot_dir(folder, builtin=False)
        servos = list(robot.servos)
        hardware = load_hardware(folder, servos)
    except RobotDataError as e:
        return _fail(str(e))
    port, baud = args.servo_bus
    protocol = args.bus_protocol or hardware.protocol
    if protocol != hardware.protocol:
        if (folder / HARDWARE_FILE).is_file():
            return _fail(f"{folder / HARDWARE_FILE} says protocol = {hardware.protocol!r}, --bus-protocol {protocol}: "
                         "fix hardware.toml or drop --bus-protocol")
        hardware = Hardware(protocol, DEFAULT_BAUD[protocol], DEFAULT_MODEL[protocol])
    bus = ServoBus(port, baud or hardware.baud, protocol, names={s.id: s.name for s in servos})
    try:
        bus.open()
    except BusError as e:
        return _fail(str(e))
    if live is None and sys.stdout.isatty():
        live = live_table([s.name for s in servos], _write)
    say(f"calibrating {robot.name} ({len(servos)} servos) on {port} at {bus.baud} baud, {protocol}"
        + (f"; replaces {target} when done" if target.exists() else ""))
    limp: list[str] = []
    try:
        calibration = calibrate(robot, bus, hardware, ask=ask or input, say=say, live=live)
    except CalibrationError as e:
        return _fail(str(e))
    except BusError as e:
        return _fail(f"{e}; nothing written", 1)
    except EOFError:
        return _fail("input ended before the procedure finished; nothing written", 1)
    finally:  # torque off again whatever happened (an error line, when there is one, stays the only line)
        limp = [f"servo {s.id} ({s.name})" for s in servos if not _quiet_torque_off(bus, s.id)]
        bus.close()
    try:
        path = save_calibration(folder, calibration, servos)
    except OSError as e:
        return _fail(f"{target}: {e.strerror or e}")
    for line in table(robot, calibration):
        say(line)
    if limp:
        say("note: torque off not acknowledged at the end by " + ", ".join(limp))
    for note in coverage_notes(robot, calibration):
        say(f"note: {note}")
    say(f"written to {path} (torque left off)")
    return 0


def _write(text: str) -> None:
    sys.stdout.write(text)
    sys.stdout.flush()


def _quiet_torque_off(bus: ServoBus, servo_id: int) -> bool:
    try:
        return bus.torque_off(servo_id)
    except Exception:
        return False


def main(args: argparse.Namespace) -> int:
    return run(args)
