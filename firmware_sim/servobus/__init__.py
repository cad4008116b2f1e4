"""A real servo bus driven from the Python board (issue 42: hardware in the loop from a PC).

``python -m firmware_sim --link pty --servo-bus /dev/ttyUSB0[:BAUD] --bus-protocol sts|dxl2`` makes
the board drive the robot's servos through a USB serial adapter instead of simulating them; MuJoCo
becomes the mirror of what the servos measure. One job per module:

* :mod:`.base` — the :class:`MotorBus` interface (LeRobot-style), fault names, :class:`Present`;
* :mod:`.ports` — the SDKs' port objects with this board's timing;
* :mod:`.sdkbus` — what both SDK buses share (one sync read, answers filed by id);
* :mod:`.feetech` — Feetech STS on ``scservo_sdk``; :mod:`.dynamixel` — Dynamixel X on ``dynamixel_sdk``;
* :mod:`.driver` — :class:`BusDriver`: rad <-> steps, step limits, start-up, faults, torque off at exit;
* :mod:`.memport` — an in-memory port the SDKs can use (fuzz targets ``bus-sts``, ``bus-dxl2``).
"""

from __future__ import annotations

import os

from firmware_sim.servobus.base import BusError, BusOpenError, BusSetupError, MotorBus, PingAnswer, Present

__all__ = ["BusError", "BusOpenError", "BusSetupError", "MotorBus", "PingAnswer", "Present", "make_bus",
           "parse_bus_spec"]


def _split_bus_spec(text: str) -> tuple[str, str]:
    """``PORT[:BAUD]`` -> (port, baud text, "" without one). The text after the last ``:`` is no baud when
    it holds a ``/``, when the whole text is a path that exists (``/dev/serial/by-path/...:1.0-port0``) or,
    in a pyserial URL, when it is the URL's own ``host:port`` (``socket://host:7000``)."""
    port, sep, baud = text.rpartition(":")
    if not sep or "/" in baud or os.path.exists(text):
        return text, ""
    if "://" in text and text.split("://", 1)[1].count(":") < 2:
        return text, ""
    return port, baud


def parse_bus_spec(text: str) -> tuple[str, int | None]:
    """``PORT[:BAUD]`` -> (port, baud or None). ``ValueError`` (one line) for an empty port or a baud that
    is not a positive whole number (``/dev/pts/0:abc``: the baud ``'abc'`` is not a number)."""
    port, baud = _split_bus_spec(text)
    if not port:
        raise ValueError(f"expected PORT[:BAUD] (e.g. /dev/ttyUSB0:1000000), got {text!r}")
    if not baud:
        return port, None
    if not baud.lstrip("-").isdigit():
        raise ValueError(f"baud {baud!r} is not a number (expected PORT[:BAUD], e.g. /dev/ttyUSB0:1000000)")
    b = int(baud)
    if b <= 0:
        raise ValueError(f"the baud rate must be > 0, got {baud} in {text!r}")
    return port, b


def make_bus(protocol: str, port: str, baud: int, *, latency_ms: float = 16.0,
             port_handler: object | None = None) -> MotorBus:
    """The :class:`MotorBus` of ``protocol`` (``"sts"`` or ``"dxl2"``) on ``port`` at ``baud`` (not opened)."""
    if protocol == "sts":
        from firmware_sim.servobus.feetech import FeetechBus

        return FeetechBus(port, baud, latency_ms, port_handler)
    if protocol == "dxl2":
        from firmware_sim.servobus.dynamixel import DynamixelBus

        return DynamixelBus(port, baud, latency_ms, port_handler)
    raise ValueError(f"bus protocol must be sts or dxl2, got {protocol!r}")
