"""Board-side safety state: emergency stop and the link watchdog (board-time driven).

Watchdog: armed by the first valid message. When no valid message has fed it for
``watchdog_us`` the board HOLDs position; a valid message before ``crouch_after_us``
more ends the hold. Otherwise the board crouches and latches WATCHDOG_FAULT until
ESTOP_CLEAR. ESTOP takes effect at the next tick and also lasts until ESTOP_CLEAR.

Servo fault (a board driving a real servo bus, :mod:`firmware_sim.servobus`): a servo that stopped
answering or reported an error latches ``servo_fault`` (:meth:`Safety.servo_faulted`): every servo
holds and frames are refused (NACK SERVO_FAULT) until ESTOP_CLEAR, as the C firmware does
(``GS_MODE_SERVO_FAULT``). Precedence: ESTOP, the latched watchdog fault, the servo fault, HOLD.
"""

from __future__ import annotations

from enum import Enum

from protocol.messages import FaultFlags

__all__ = ["Mode", "Safety"]


class Mode(Enum):
    RUN = "run"  # following frames
    HOLD = "hold"  # watchdog: link silent, holding position
    CROUCH = "crouch"  # watchdog fault latched: crouching, frames refused
    ESTOP = "estop"  # emergency stop: holding, frames refused
    SERVO_FAULT = "servo_fault"  # a servo on the bus failed: every servo holds, frames refused


class Safety:
    """Tracks estop and watchdog state; :meth:`update` is called once per tick with board time."""

    def __init__(self, watchdog_us: int, crouch_after_us: int) -> None:
        self.watchdog_us = watchdog_us
        self.crouch_after_us = crouch_after_us
        self.armed = False
        self.last_feed_us = 0
        self.hold_since_us: int | None = None
        self.fault_latched = False
        self.estopped = False
        self.servo_fault = False
        self.watchdog_trips = 0

    def feed(self, t_us: int) -> bool:
        """A valid message (or, in lockstep, an applied frame) at ``t_us``; True if it ended a HOLD."""
        self.armed = True
        self.last_feed_us = max(self.last_feed_us, t_us)
        if self.hold_since_us is not None and not self.fault_latched:
            self.hold_since_us = None
            return True
        return False

    def estop(self) -> None:
        self.estopped = True

    def servo_faulted(self) -> None:
        """A servo on the bus failed: SERVO_FAULT until ESTOP_CLEAR."""
        self.servo_fault = True

    def clear(self, t_us: int) -> None:
        """ESTOP_CLEAR: release estop, the latched watchdog fault and the servo fault."""
        self.estopped = False
        self.fault_latched = False
        self.servo_fault = False
        self.hold_since_us = None
        self.last_feed_us = t_us

    def update(self, t_us: int) -> tuple[Mode, bool]:
        """Advance the watchdog to board time ``t_us``; returns (mode, entered a new mode now)."""
        if (self.hold_since_us is None and not self.estopped and not self.fault_latched and not self.servo_fault
                and (not self.armed or t_us - self.last_feed_us <= self.watchdog_us)):
            return Mode.RUN, False  # the per-tick common case: running, fed in time
        before = self.mode
        if self.armed and not self.estopped and not self.fault_latched:
            if self.hold_since_us is None and t_us - self.last_feed_us > self.watchdog_us:
                self.hold_since_us = t_us
                self.watchdog_trips += 1
            if self.hold_since_us is not None and t_us - self.hold_since_us >= self.crouch_after_us:
                self.fault_latched = True
        after = self.mode
        return after, after is not before

    @property
    def mode(self) -> Mode:
        if self.estopped:
            return Mode.ESTOP
        if self.fault_latched:
            return Mode.CROUCH
        if self.servo_fault:
            return Mode.SERVO_FAULT
        if self.hold_since_us is not None:
            return Mode.HOLD
        return Mode.RUN

    @property
    def flags(self) -> FaultFlags:
        f = FaultFlags.NONE
        if self.estopped:
            f |= FaultFlags.ESTOP
        if self.hold_since_us is not None and not self.fault_latched:
            f |= FaultFlags.WATCHDOG_HOLD
        if self.fault_latched:
            f |= FaultFlags.WATCHDOG_FAULT
        if self.servo_fault:
            f |= FaultFlags.SERVO_FAULT
        return f
