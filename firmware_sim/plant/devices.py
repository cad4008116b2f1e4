"""The devices on the emulated servo bus and their control tables (registers).

``ServoDevice``: an STS3215-class servo (model number 777, 4096 steps per turn). Registers
(little-endian words; the STS memory map): 0 firmware major, 1 minor, 3-4 model number, 5 id,
6 baud rate (0 = 1 Mbaud), 7 return delay (2 us units), 9-10 / 11-12 min / max angle limit
(steps), 40 torque enable, 41 acceleration, 42-43 goal position (steps), 44-45 goal time, 46-47
goal speed, 55 lock, 56-57 present position (steps), 58-59 present speed (steps/s, bit 15 =
sign), 60-61 present load (0.1 % of full torque, bit 10 = sign), 62 present voltage (0.1 V),
63 present temperature (deg C), 66 moving, 69-70 present current (always 0). A view over the
servo's protocol-neutral :class:`~firmware_sim.plant.servo.ServoState`; torque enable 0 makes the
servo limp in the world. Layout source: Feetech's STS3215 memory table and ``scservo_sdk``
(``feetech-servo-sdk``) examples' register names (``ADDR_STS_*``).

``ImuDevice`` (id 0xF0, model 0x4D55): 56-61 roll, pitch, yaw as int16 x 1e-4 rad (the IMU a
board would read; on a real robot it sits on I2C or SPI, here on the same bus for simplicity).

``ProbeDevice`` (id 0xF1, model 0x4754): **emulator only**, the ground truth no real robot has:
56-83 base position x y z (m) and orientation quaternion w x y z as IEEE float32, 84 movable scene
objects, 85 how many of them toppled. The C firmware forwards it as SIM_STATE when it answers at
boot; on real hardware nothing answers there and the firmware sends no SIM_STATE.
"""

from __future__ import annotations

import struct

from firmware_sim.plant.feetech import from_sign_magnitude
from firmware_sim.plant.servo import Fault, ServoState

__all__ = ["Device", "IMU_ID", "ImuDevice", "PROBE_ID", "ProbeDevice", "REG", "STS_ERROR_BITS", "ServoDevice", "STS_MODEL",
           "sts_error"]

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

    @property
    def return_delay_us(self) -> int:
        """The delay before this device's status packet (register 7, 2 us units)."""
        return self.table[REG.RETURN_DELAY] * 2

    @property
    def error(self) -> int:
        """The STS status error byte (0: no condition)."""
        return 0

    @property
    def model(self) -> int:
        return self.u16(REG.MODEL)

    @property
    def firmware(self) -> int:
        return self.table[0]

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


#: the STS status error bits of each fault (scservo_sdk protocol_packet_handler.py: ERRBIT_VOLTAGE 1,
#: ERRBIT_OVERHEAT 4, ERRBIT_OVERLOAD 32; ERRBIT_ANGLE 2 and ERRBIT_OVERELE 8 are not injected)
STS_ERROR_BITS: dict[int, int] = {Fault.VOLTAGE: 0x01, Fault.OVERHEAT: 0x04, Fault.OVERLOAD: 0x20}
_STS_ERROR = [sum(bit for f, bit in STS_ERROR_BITS.items() if fault & f) for fault in range(8)]
#: present position, speed, load (56..61), voltage (62), temperature (63)
_PRESENT = struct.Struct("<3HBB")


def sts_error(fault: int) -> int:
    """The STS status packet's error byte for ``fault`` (:class:`Fault` bits)."""
    return _STS_ERROR[fault & 7]


class ServoDevice(Device):
    """The STS control table as a view over one :class:`ServoState`.

    Registers the servo state owns are rendered on READ (present position clipped to 0..4095,
    speed sign-magnitude at bit 15, load in 0.1 % sign-magnitude at bit 10, voltage, temperature,
    moving, torque enable, model number) and parsed on WRITE (angle limits 9..12, return delay 7,
    torque enable 40, goal position 42..43 as sign-magnitude at bit 15); the others are stored.
    """

    def __init__(self, state: ServoState) -> None:
        super().__init__(state.id, 71, state.model)
        self.state = state
        self.set_u16(REG.MIN_ANGLE, state.min_steps)
        self.set_u16(REG.MAX_ANGLE, state.max_steps)
        self.set_u16(REG.GOAL_POSITION, state.goal_steps)
        self.table[REG.RETURN_DELAY] = state.return_delay_us // 2
        self._render()

    @property
    def return_delay_us(self) -> int:
        return self.state.return_delay_us

    @property
    def error(self) -> int:
        return _STS_ERROR[self.state.fault & 7]

    def _render(self) -> None:
        st, t = self.state, self.table
        pos = st.present_steps
        speed = round(st.speed_steps_s)
        load = round(st.load * 1000)
        _PRESENT.pack_into(t, REG.PRESENT_POSITION, 0 if pos < 0 else 4095 if pos > 4095 else pos,
                           min(32767, speed) if speed >= 0 else min(32767, -speed) | 0x8000,
                           min(1000, load) if load >= 0 else min(1000, -load) | 0x400,
                           st.voltage_dv & 0xFF, st.temperature_c & 0xFF)
        t[REG.MOVING] = 1 if speed > 2 or speed < -2 else 0
        t[REG.TORQUE_ENABLE] = 1 if st.torque else 0
        t[REG.MODEL] = st.model & 0xFF
        t[REG.MODEL + 1] = st.model >> 8 & 0xFF

    def read(self, addr: int, n: int) -> bytes | None:
        self._render()
        return super().read(addr, n)

    def write(self, addr: int, data: bytes) -> bool:
        self._render()
        if not super().write(addr, data):
            return False
        st, end = self.state, addr + len(data)
        if addr <= REG.RETURN_DELAY < end:
            st.return_delay_us = self.table[REG.RETURN_DELAY] * 2
        if addr < REG.MAX_ANGLE + 2 and end > REG.MIN_ANGLE:
            st.min_steps, st.max_steps = self.u16(REG.MIN_ANGLE), self.u16(REG.MAX_ANGLE)
        if addr <= REG.TORQUE_ENABLE < end:
            st.torque = bool(self.table[REG.TORQUE_ENABLE]) and not st.fault & st.shutdown
        if addr < REG.GOAL_POSITION + 2 and end > REG.GOAL_POSITION:
            st.goal_steps = from_sign_magnitude(self.u16(REG.GOAL_POSITION), 15)
        return True

    @property
    def goal(self) -> int:
        """Goal position in steps, limited to the angle limits (as the servo does)."""
        return self.state.goal


class ImuDevice(Device):
    def __init__(self) -> None:
        super().__init__(IMU_ID, 64, IMU_MODEL)


class ProbeDevice(Device):
    def __init__(self) -> None:
        super().__init__(PROBE_ID, 88, PROBE_MODEL)
