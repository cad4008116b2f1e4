"""The controller side of a servo bus, protocol-neutral: what the board needs from it, nothing more.

:class:`MotorBus` is the small interface the board's bus layer (:mod:`firmware_sim.servobus.driver`)
uses, after LeRobot's ``MotorsBus`` (``lerobot/motors/motors_bus.py``): open and close the port,
ping a servo (model number), torque on/off, and per control tick ONE sync read of the present values
of every servo and ONE sync write of every goal. Implementations sit on the vendors' own SDKs
(:mod:`firmware_sim.servobus.feetech`, :mod:`firmware_sim.servobus.dynamixel`): the SDK builds and
checks the packets, this package decides what to send and what an answer means.

Units on this interface are the servos' raw register units: positions in steps (0..4095, 4096 a
turn), speeds in steps/s, load as a fraction of full torque (-1..1). Conversion to joint angles is
the driver's (:mod:`robots.hardware`).

Errors: only :meth:`MotorBus.open` raises (:class:`BusOpenError`); a servo that does not answer, a
garbled answer or a servo's error bits are results (:class:`Present`, :class:`PingAnswer`), never
exceptions, so a tick always completes.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import ClassVar

__all__ = [
    "BusError",
    "BusOpenError",
    "BusSetupError",
    "CORRUPT",
    "MotorBus",
    "OVERHEAT",
    "OVERLOAD",
    "PingAnswer",
    "Present",
    "TIMEOUT",
    "VOLTAGE",
    "TORQUE_OFF_FAULTS",
]

#: what went wrong with a servo, as the one-line reports name it
TIMEOUT = "not answering on the servo bus"
CORRUPT = "garbled answers (checksum errors)"
OVERLOAD = "overload"
OVERHEAT = "overheating"
VOLTAGE = "voltage"
#: a servo reporting one of these gets its torque switched off at once
TORQUE_OFF_FAULTS = frozenset({OVERLOAD, OVERHEAT})


class BusError(Exception):
    """A servo bus that cannot be used; ``str(e)`` is the one line for the user."""


class BusOpenError(BusError):
    """The port is missing or refuses the baud rate."""


class BusSetupError(BusError):
    """Start-up found a servo missing, answering twice or garbled, or of the wrong model."""


@dataclass(frozen=True)
class PingAnswer:
    """One servo's answer to a ping: its model number, or why there is none (``fault``)."""

    model: int | None = None
    fault: str | None = None


@dataclass(frozen=True)
class Present:
    """One servo's present values from one sync read.

    ``position`` (steps) is None when no valid answer came (``comm`` says why: :data:`TIMEOUT` or
    :data:`CORRUPT`); ``speed`` in steps/s; ``load`` a fraction of full torque (-1..1, signed as the
    position); ``errors``: the servo's own error bits as fault names (:data:`OVERLOAD`, ...)."""

    position: int | None
    speed: int = 0
    load: float = 0.0
    errors: tuple[str, ...] = ()
    comm: str | None = None


@dataclass
class MotorBus(ABC):
    """A servo bus on ``port`` at ``baud`` bit/s. ``latency_ms``: how long an answer may take beyond its
    bytes' wire time (the SDKs' ``LATENCY_TIMER``: a USB adapter's latency timer; a lockstep board may
    wait longer, its time is virtual). ``port_handler``: an SDK port object to use instead of opening
    ``port`` (the fuzz targets' in-memory port)."""

    port: str
    baud: int
    latency_ms: float = 16.0
    port_handler: object | None = None
    #: how many packets were sent and answers seen garbled, since open (for the exit line)
    counts: dict[str, int] = field(default_factory=lambda: {"sync_reads": 0, "sync_writes": 0, "corrupt": 0,
                                                             "timeouts": 0})

    #: model numbers the pings found, by servo id
    models: dict[int, int] = field(default_factory=dict)

    protocol: ClassVar[str] = ""
    #: the position register's raw span (4096-step servos) and bytes a goal takes on the wire
    goal_bytes: ClassVar[int] = 2

    @abstractmethod
    def open(self) -> None:
        """Open the port at the baud rate; :class:`BusOpenError` (one line) when it cannot."""

    @abstractmethod
    def close(self) -> None:
        """Close the port (never raises)."""

    @abstractmethod
    def ping(self, servo_id: int) -> PingAnswer:
        """Ping one servo and read its model number; a second answer or garbled bytes are a fault."""

    @abstractmethod
    def set_torque(self, ids: Sequence[int], on: bool) -> None:
        """Torque enable on/off for ``ids`` in one SYNC WRITE (no answer; never raises)."""

    @abstractmethod
    def read(self, ids: Sequence[int]) -> dict[int, Present]:
        """ONE sync read of position, speed, load and error state of ``ids``; every id gets an entry."""

    @abstractmethod
    def write_goals(self, goals: Mapping[int, int]) -> None:
        """ONE sync write of goal positions (steps) by servo id (no answer; never raises)."""

    def prepare(self, ids: Sequence[int]) -> bool:
        """Per-protocol set-up after the pings, torque still off (Dynamixel: indirect addresses); True
        when the fast path was set up."""
        return True

    #: the servos' factory return delay (us) before each status packet (Dynamixel X: 250 x 2 us; STS: 0)
    default_return_delay_us: ClassVar[float] = 0.0
    #: the largest return delay (us) start-up found on the bus (``zero_return_delay``); None: not set up
    measured_return_delay_us: float | None = field(default=None, init=False)

    @property
    def return_delay_us(self) -> float:
        """The return delay (us) the bus timing counts with: as set up at start-up, else the factory one."""
        d = self.measured_return_delay_us
        return self.default_return_delay_us if d is None else d

    def zero_return_delay(self, ids: Sequence[int]) -> float:
        """Write the servos' return delay to 0 where they take it; the largest left (us)."""
        return self.return_delay_us

    def tick_bytes(self, n: int) -> int:
        """Bytes on the wire per control tick for ``n`` servos (the sync read both ways, the sync write)."""
        return 0

    def tick_seconds(self, n: int) -> float:
        """Bus time (s) of one control tick for ``n`` servos at :attr:`baud`: 10 bits a byte plus each
        status packet's return delay."""
        return self.tick_bytes(n) * 10 / self.baud + n * self.return_delay_us / 1e6
