"""The devices on the emulated servo bus and their control tables (registers).

``ServoDevice``: an STS3215-class servo (model number 777, 4096 steps per turn). Registers
(little-endian words; the STS memory map): 0 firmware major, 1 minor, 3-4 model number, 5 id,
6 baud rate (0 = 1 Mbaud), 7 return delay (2 us units), 9-10 / 11-12 min / max angle limit
(steps), 40 torque enable, 41 acceleration, 42-43 goal position (steps), 44-45 goal time, 46-47
goal speed, 55 lock, 56-57 present position (steps), 58-59 present speed (steps/s, bit 15 =
sign), 60-61 present load (0.1 % of full torque, bit 10 = sign), 62 present voltage (0.1 V),
63 present temperature (deg C), 66 moving, 69-70 present current. Torque enable is stored; the
emulated servo always drives (a limp servo is not modelled).

``ImuDevice`` (id 0xF0, model 0x4D55): 56-61 roll, pitch, yaw as int16 x 1e-4 rad (the IMU a
board would read; on a real robot it sits on I2C or SPI, here on the same bus for simplicity).

``ProbeDevice`` (id 0xF1, model 0x4754): **emulator only**, the ground truth no real robot has:
56-83 base position x y z (m) and orientation quaternion w x y z as IEEE float32, 84 movable scene
objects, 85 how many of them toppled. The C firmware forwards it as SIM_STATE when it answers at
boot; on real hardware nothing answers there and the firmware sends no SIM_STATE.
"""

from __future__ import annotations

import struct

__all__ = ["Device", "IMU_ID", "ImuDevice", "PROBE_ID", "ProbeDevice", "REG", "ServoDevice", "STS_MODEL"]

IMU_ID = 0xF0
PROBE_ID = 0xF1
STS_MODEL = 777  # what an STS3215 reports at register 3
IMU_MODEL = 0x4D55
PROBE_MODEL = 0x4754


class REG:
    MODEL = 3
    ID = 5
    BAUD = 6
    RETURN_DELAY = 7
    MIN_ANGLE = 9
    MAX_ANGLE = 11
    TORQUE_ENABLE = 40
    ACCELERATION = 41
    GOAL_POSITION = 42
    GOAL_TIME = 44
    GOAL_SPEED = 46
    LOCK = 55
    PRESENT_POSITION = 56
    PRESENT_SPEED = 58
    PRESENT_LOAD = 60
    PRESENT_VOLTAGE = 62
    PRESENT_TEMPERATURE = 63
    MOVING = 66
    PRESENT_CURRENT = 69


class Device:
    """A bus device: an id and a register file; READ/WRITE outside it are refused (no answer)."""

    def __init__(self, dev_id: int, size: int, model: int) -> None:
        self.id = dev_id
        self.table = bytearray(size)
        self.table[0] = 3  # firmware version 3.x
        self.table[1] = 10
        self.set_u16(REG.MODEL, model)
        self.table[REG.ID] = dev_id
        self.alive = True  # False: the device stopped answering (a fault the tests inject)

    def set_u16(self, addr: int, v: int) -> None:
        self.table[addr:addr + 2] = struct.pack("<H", v & 0xFFFF)

    def u16(self, addr: int) -> int:
        return int(struct.unpack_from("<H", self.table, addr)[0])

    def read(self, addr: int, n: int) -> bytes | None:
        if n < 1 or addr < 0 or addr + n > len(self.table):
            return None
        return bytes(self.table[addr:addr + n])

    def write(self, addr: int, data: bytes) -> bool:
        """Store ``data`` at ``addr``; False (refused) outside the table or over read-only registers."""
        if addr < 0 or addr + len(data) > len(self.table) or addr < REG.MIN_ANGLE and addr != REG.RETURN_DELAY:
            return False
        self.table[addr:addr + len(data)] = data
        return True


class ServoDevice(Device):
    """One servo's registers; the world fills the present values and reads the goal."""

    def __init__(self, dev_id: int, step_lo: int, step_hi: int, centre: int) -> None:
        super().__init__(dev_id, 71, STS_MODEL)
        self.set_u16(REG.MIN_ANGLE, step_lo)
        self.set_u16(REG.MAX_ANGLE, step_hi)
        self.table[REG.TORQUE_ENABLE] = 1
        self.set_u16(REG.GOAL_POSITION, centre)
        self.set_u16(REG.PRESENT_POSITION, centre)
        self.table[REG.PRESENT_VOLTAGE] = 74
        self.table[REG.PRESENT_TEMPERATURE] = 30

    @property
    def goal(self) -> int:
        """Goal position in steps, limited to the angle limits (as the servo does)."""
        raw = self.u16(REG.GOAL_POSITION)
        v = -(raw & 0x7FFF) if raw & 0x8000 else raw
        return max(self.u16(REG.MIN_ANGLE), min(self.u16(REG.MAX_ANGLE), v))


class ImuDevice(Device):
    def __init__(self) -> None:
        super().__init__(IMU_ID, 64, IMU_MODEL)


class ProbeDevice(Device):
    def __init__(self) -> None:
        super().__init__(PROBE_ID, 88, PROBE_MODEL)
