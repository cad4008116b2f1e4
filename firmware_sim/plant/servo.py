"""One servo's state, protocol-neutral: what the world and both wire protocols' control tables share.

The world (:mod:`firmware_sim.plant.world`) writes the present values each control period and reads
the goal, limits and torque; a protocol's control table (:mod:`firmware_sim.plant.devices` for
Feetech STS, :mod:`firmware_sim.plant.dxl_table` for Dynamixel X) is a view that renders these
fields into its register layout on READ and parses its registers back on WRITE.

Units: positions are raw register steps of a 4096-step servo (:data:`robots.hardware.STEP_CENTRE`
= 2048 at the horn centre; the servo's own frame, after any injected offset/reversal); speeds
steps/s; load a signed fraction of full torque (-1..1); temperature deg C; voltage 0.1 V.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Fault", "ServoState"]


class Fault:
    """Hardware conditions a servo reports, as bits of an int (each protocol maps them to its own
    error bits). Plain ints, not an ``enum.IntFlag``: they are tested on every status packet."""

    NONE = 0
    VOLTAGE = 1
    OVERHEAT = 2
    OVERLOAD = 4
    #: the faults that switch a servo's torque off by default (its own protection; a Dynamixel's
    #: Shutdown register, address 63, sets them per servo: :attr:`ServoState.shutdown`)
    STOPS_TORQUE = OVERHEAT | OVERLOAD


@dataclass
class ServoState:
    """The protocol-neutral state of one servo (see the module docstring for the units)."""

    id: int
    model: int
    min_steps: int
    max_steps: int
    goal_steps: int
    torque: bool = True
    present_steps: int = 2048  # unclipped: the STS register clips it to 0..4095
    speed_steps_s: float = 0.0  # signed, servo frame
    load: float = 0.0  # signed fraction of full torque, servo frame
    temperature_c: int = 30
    voltage_dv: int = 74
    fault: int = Fault.NONE  # Fault bits
    shutdown: int = Fault.STOPS_TORQUE  # the Fault bits that turn torque off (and keep it off)
    return_delay_us: int = 0

    @property
    def goal(self) -> int:
        """The goal held to the limits (steps), as the servo drives it."""
        return max(self.min_steps, min(self.max_steps, self.goal_steps))

    @property
    def moving(self) -> bool:
        return abs(round(self.speed_steps_s)) > 2
