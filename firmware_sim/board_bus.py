"""A board's side of a real servo bus: the exchange each bus period, the mirror, the SERVO_FAULT NACKs.

Held by :class:`firmware_sim.board.Board` once :meth:`Board.attach_bus` ran. Each bus period
(:attr:`firmware_sim.servobus.driver.BusDriver.every` ticks) the servo model's speed-limited command
(rad, servo order) goes to the servos as goals (one SYNC WRITE, clamped by the driver to the
calibrated step limits) and what they measure comes back (one SYNC READ) and is written into the
model (:meth:`BusBridge.mirror`: ``qpos``/``qvel``, ``mj_forward``, actuator forces; no physics).
Each servo failure the driver reports becomes an unsolicited NACK SERVO_FAULT (msg_type SERVO_FRAME,
the sequence number of the last message the board handled), at most 16 waiting, sent with the next
tick's output (:meth:`BusBridge.take_out`); latching the fault is the board's (its safety state).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import mujoco

from firmware_sim.board_reports import BoardReports
from protocol.messages import Message, MsgType, Nack, NackReason

if TYPE_CHECKING:
    from firmware_sim.servobus.driver import BusDriver, BusFault

__all__ = ["SERVO_FAULT_DETAIL", "BusBridge"]

#: the detail of a NACK SERVO_FAULT refusing a frame before any servo named its failure
SERVO_FAULT_DETAIL = "a servo failed on the servo bus; send ESTOP_CLEAR"


class BusBridge:
    """``bus`` driving the servos whose model is ``model``/``reports.data`` (the board's)."""

    def __init__(self, bus: BusDriver, model: mujoco.MjModel, reports: BoardReports) -> None:
        self.bus = bus
        self.model = model
        self.reports = reports
        #: unsolicited NACK SERVO_FAULTs for the next tick's output
        self.out: list[Message] = []
        #: the detail of the NACK SERVO_FAULT that refuses frames while the fault is latched
        self.fault_detail = SERVO_FAULT_DETAIL

    def mirror(self, m: Any) -> None:
        """Measured positions (rad), speeds (rad/s) and efforts (N*m) into the model: kinematics only."""
        r = self.reports
        data = r.data
        data.qpos[r.qpos_at] = m.positions
        data.qvel[r.dof_at] = m.speeds
        mujoco.mj_forward(self.model, data)
        data.actuator_force[r.ctrl_at] = m.efforts

    def exchange(self, cmd: list[float], now_us: int, last_rx_seq: int) -> list[BusFault]:
        """One bus period at board time ``now_us``: ``cmd`` (rad) out as goals, the measurement into the
        model; returns the servo faults the driver reported (each also queued as a NACK)."""
        bus = self.bus
        self.mirror(bus.exchange(cmd, now_us))
        faults = bus.take_faults()
        for f in faults:
            self.out.append(Nack(last_rx_seq & 0xFFFF, MsgType.SERVO_FRAME, NackReason.SERVO_FAULT,
                                 f.detail.encode("ascii", "replace").decode("ascii")[:64]))
        if faults:
            del self.out[:-16]
        return faults

    def take_out(self) -> list[Message]:
        """The queued NACKs (the queue is emptied)."""
        out, self.out = self.out, []
        return out
