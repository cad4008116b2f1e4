"""What both of firmware_sim's servo ends know about a robot's servos: the torque a present-load reading means.

The emulator's plant (:mod:`firmware_sim.plant.world`), the C firmware's generated servo table
(:mod:`firmware_sim.cfirmware.servo_table`) and the real-bus driver (:mod:`firmware_sim.servobus.driver`)
import it, so none of them imports another for it (cfirmware runs the plant, never the reverse). The
step maths (register centre, joint angle <-> register steps, the goal range) is the robot's data
contract and lives in :mod:`robots.hardware`.
"""

from __future__ import annotations

from robots.description import Robot

__all__ = ["load_full_scale"]


def load_full_scale(robot: Robot) -> list[float]:
    """Per servo, the torque (N*m) of a 100 % present-load reading (reading 1000): the servo table's stall
    torque, else the MJCF actuator's force range (1.0 where that is unset)."""
    stall = robot.servos.model.stall_torque
    if stall:
        return [float(stall)] * robot.servo_count
    model = robot.model().model
    out = []
    for s in robot.servos:
        import mujoco

        aid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, s.actuator)
        lo, hi = model.actuator_forcerange[aid]
        full = max(abs(float(lo)), abs(float(hi)))
        out.append(full if full > 0 else 1.0)
    return out
