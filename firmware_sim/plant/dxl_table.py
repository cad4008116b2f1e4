"""The Dynamixel X-series control table as a view over one servo's :class:`ServoState`.

Layout (XL330-M288-T, model 1200, the default; XM430-W350, model 1020, shares these addresses;
little-endian; ``R`` read-only, ``E`` EEPROM: writable only with torque off)::

    0  model number (2, R)      6  firmware version (R)   7  id (E)          8  baud rate (E)
    9  return delay (E, 2 us)  10  drive mode (E)         11 operating mode (E, 3 = position)
    20 homing offset (4, E)    31 temperature limit (E)   32 / 34 max / min voltage limit (2, E, 0.1 V)
    44 velocity limit (4, E)   48 max position limit (4, E)   52 min position limit (4, E)
    64 torque enable            65 LED                     68 status return level
    70 hardware error status (R: bit 0 input voltage, 2 overheating, 3 motor encoder,
       4 electrical shock, 5 overload)
    116 goal position (4)      122 moving (R)             124 present PWM (2, R, signed)
    126 present current (2, R, signed)   128 present velocity (4, R, signed, 0.229 rpm)
    132 present position (4, R, signed)  144 present input voltage (2, R, 0.1 V)
    146 present temperature (R, deg C)
    168..223 indirect address 1..28 (2 each, writable with torque off)
    224..251 indirect data 1..28 (1 each: reads and writes go to the address the matching
             indirect address holds)

Errors (the status packet's low 7 bits, :class:`~firmware_sim.plant.dynamixel.Result`): outside
0..251 -> data range; a write to a read-only address, or to EEPROM / an indirect address with
torque on -> access; a write that splits a multi-byte item -> data length; a goal position outside
the min/max position limits -> data limit (nothing written).

Sources: ROBOTIS e-Manual, XL330-M288-T and XM430-W350 "Control Table"
(emanual.robotis.com/docs/en/dxl/x/xl330-m288/, .../x/xm430-w350/); the SDK's
``dynamixel_sdk`` examples (``indirect_address.py``: indirect addresses are written with torque off).
Modelled: position mode only (operating mode and drive mode are stored, not acted on); homing offset
is added to present position and subtracted from the goal. Present PWM and current are the load
fraction times 885 and times 1750 mA (XL330's PWM and current limits): an approximation.
"""

from __future__ import annotations

import struct

from firmware_sim.plant.devices import Device
from firmware_sim.plant.dynamixel import Result
from firmware_sim.plant.servo import Fault, ServoState

__all__ = ["ADDR", "DXL_BAUD_CODES", "DxlRegisterFile", "DxlServo", "HW_ERROR_BITS", "MODEL_XL330", "MODEL_XM430",
           "hardware_error"]

MODEL_XL330 = 1200
MODEL_XM430 = 1020
FIRMWARE = 52
TABLE_SIZE = 252
#: baud rate register value -> bits per second
DXL_BAUD_CODES: dict[int, int] = {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000,
                                  6: 4_000_000, 7: 4_500_000}
#: hardware error status bits of each fault
HW_ERROR_BITS: dict[Fault, int] = {Fault.VOLTAGE: 0x01, Fault.OVERHEAT: 0x04, Fault.OVERLOAD: 0x20}
RPM_UNIT = 0.229
PWM_LIMIT = 885
CURRENT_LIMIT_MA = 1750
N_INDIRECT = 28


class ADDR:
    MODEL = 0
    FIRMWARE = 6
    ID = 7
    BAUD = 8
    RETURN_DELAY = 9
    DRIVE_MODE = 10
    OPERATING_MODE = 11
    HOMING_OFFSET = 20
    TEMPERATURE_LIMIT = 31
    MAX_VOLTAGE = 32
    MIN_VOLTAGE = 34
    VELOCITY_LIMIT = 44
    MAX_POSITION = 48
    MIN_POSITION = 52
    EEPROM_END = 64
    TORQUE_ENABLE = 64
    LED = 65
    STATUS_RETURN_LEVEL = 68
    HARDWARE_ERROR = 70
    GOAL_POSITION = 116
    MOVING = 122
    PRESENT_PWM = 124
    PRESENT_CURRENT = 126
    PRESENT_VELOCITY = 128
    PRESENT_POSITION = 132
    PRESENT_VOLTAGE = 144
    PRESENT_TEMPERATURE = 146
    INDIRECT_ADDRESS = 168
    INDIRECT_DATA = 224


#: (address, size) of every multi-byte item a write must not split
_ITEMS: list[tuple[int, int]] = [
    (0, 2), (2, 4), (20, 4), (24, 4), (32, 2), (34, 2), (36, 2), (38, 2), (44, 4), (48, 4), (52, 4), (76, 2),
    (78, 2), (80, 2), (82, 2), (84, 2), (88, 2), (90, 2), (100, 2), (102, 2), (104, 4), (108, 4), (112, 4),
    (116, 4), (120, 2), (124, 2), (126, 2), (128, 4), (132, 4), (136, 4), (140, 4), (144, 2),
    *((ADDR.INDIRECT_ADDRESS + 2 * k, 2) for k in range(N_INDIRECT)),
]
_READ_ONLY = {*range(0, 7), 69, 70, *range(120, 148)}
_BAUD_CODE = {v: k for k, v in DXL_BAUD_CODES.items()}


def hardware_error(fault: Fault) -> int:
    """The hardware error status register (address 70) for ``fault``."""
    return sum(bit for f, bit in HW_ERROR_BITS.items() if fault & f)


def _splits_item(addr: int, end: int) -> bool:
    return any(a < addr < a + n or a < end < a + n for a, n in _ITEMS)


class DxlServo:
    """One Dynamixel X servo's control table over ``state`` (see the module docstring)."""

    def __init__(self, state: ServoState, *, baud: int = 57600) -> None:
        self.state = state
        t = self.table = bytearray(TABLE_SIZE)
        t[ADDR.FIRMWARE] = FIRMWARE
        t[ADDR.ID] = state.id
        t[ADDR.BAUD] = _BAUD_CODE.get(baud, 1)
        t[ADDR.RETURN_DELAY] = state.return_delay_us // 2
        t[ADDR.OPERATING_MODE] = 3
        t[ADDR.TEMPERATURE_LIMIT] = 70
        struct.pack_into("<HH", t, ADDR.MAX_VOLTAGE, 70, 35)
        struct.pack_into("<I", t, ADDR.VELOCITY_LIMIT, 445)
        struct.pack_into("<ii", t, ADDR.MAX_POSITION, state.max_steps, state.min_steps)
        t[ADDR.STATUS_RETURN_LEVEL] = 2
        struct.pack_into("<i", t, ADDR.GOAL_POSITION, state.goal_steps)
        for k in range(N_INDIRECT):
            struct.pack_into("<H", t, ADDR.INDIRECT_ADDRESS + 2 * k, ADDR.INDIRECT_DATA + k)
        self._render()

    @property
    def id(self) -> int:
        return self.state.id

    @property
    def model(self) -> int:
        return self.state.model

    @property
    def firmware(self) -> int:
        return self.table[ADDR.FIRMWARE]

    @property
    def return_delay_us(self) -> int:
        return self.state.return_delay_us

    @property
    def alert(self) -> bool:
        """Bit 7 of every status packet: the hardware error status is non-zero."""
        return self.state.fault != Fault.NONE

    def _homing(self) -> int:
        return int(struct.unpack_from("<i", self.table, ADDR.HOMING_OFFSET)[0])

    def _render(self) -> None:
        st, t = self.state, self.table
        struct.pack_into("<H", t, ADDR.MODEL, st.model & 0xFFFF)
        t[ADDR.TORQUE_ENABLE] = 1 if st.torque else 0
        t[ADDR.HARDWARE_ERROR] = hardware_error(st.fault)
        t[ADDR.MOVING] = 1 if st.moving else 0
        rpm = st.speed_steps_s / 4096 * 60
        load = max(-1.0, min(1.0, st.load))
        struct.pack_into("<hhii", t, ADDR.PRESENT_PWM, round(load * PWM_LIMIT), round(load * CURRENT_LIMIT_MA),
                         int(round(rpm / RPM_UNIT)), st.present_steps + self._homing())
        struct.pack_into("<HB", t, ADDR.PRESENT_VOLTAGE, st.voltage_dv & 0xFFFF, st.temperature_c & 0xFF)

    def _map(self, addr: int, n: int) -> list[int]:
        """Control-table addresses of ``addr .. addr+n-1`` with indirect data resolved."""
        out = []
        for a in range(addr, addr + n):
            if ADDR.INDIRECT_DATA <= a < ADDR.INDIRECT_DATA + N_INDIRECT:
                k = a - ADDR.INDIRECT_DATA
                a = int(struct.unpack_from("<H", self.table, ADDR.INDIRECT_ADDRESS + 2 * k)[0])
            out.append(a)
        return out

    def read(self, addr: int, n: int) -> tuple[int, bytes]:
        """(result, data): ``n`` bytes from ``addr`` (data range error outside the table)."""
        if n < 1 or addr < 0 or addr + n > TABLE_SIZE:
            return Result.DATA_RANGE, b""
        self._render()
        if addr + n <= ADDR.INDIRECT_DATA:
            return Result.OK, bytes(self.table[addr:addr + n])
        mapped = self._map(addr, n)
        if any(not 0 <= a < TABLE_SIZE for a in mapped):
            return Result.DATA_RANGE, b""
        return Result.OK, bytes(self.table[a] for a in mapped)

    def write(self, addr: int, data: bytes) -> int:
        """Write ``data`` at ``addr``; returns the result code (:class:`Result`; OK when written)."""
        n = len(data)
        if n < 1 or addr < 0 or addr + n > TABLE_SIZE:
            return Result.DATA_RANGE
        if addr + n > ADDR.INDIRECT_DATA:  # resolve indirect data, write the runs of mapped addresses
            direct = addr < ADDR.INDIRECT_DATA
            pairs = list(zip(self._map(addr, n), data))
            if direct:
                r = self._write_direct(addr, bytes(data[:ADDR.INDIRECT_DATA - addr]))
                if r != Result.OK:
                    return r
                pairs = pairs[ADDR.INDIRECT_DATA - addr:]
            runs: list[tuple[int, bytearray]] = []
            for a, b in pairs:
                if runs and runs[-1][0] + len(runs[-1][1]) == a:
                    runs[-1][1].append(b)
                else:
                    runs.append((a, bytearray([b])))
            for a, chunk in runs:
                if a >= ADDR.INDIRECT_DATA:
                    return Result.ACCESS  # an indirect address pointing at indirect data
                r = self._write_direct(a, bytes(chunk))
                if r != Result.OK:
                    return r
            return Result.OK
        return self._write_direct(addr, bytes(data))

    def _write_direct(self, addr: int, data: bytes) -> int:
        st, t = self.state, self.table
        end = addr + len(data)
        if end > TABLE_SIZE or addr < 0:
            return Result.DATA_RANGE
        if any(a in _READ_ONLY for a in range(addr, end)):
            return Result.ACCESS
        torque_on = st.torque and not (addr <= ADDR.TORQUE_ENABLE < end)
        if torque_on and (addr < ADDR.EEPROM_END or addr < ADDR.INDIRECT_DATA and end > ADDR.INDIRECT_ADDRESS):
            return Result.ACCESS
        if _splits_item(addr, end):
            return Result.DATA_LENGTH
        new = bytearray(t)
        new[addr:end] = data
        lo, hi = struct.unpack_from("<ii", new, ADDR.MAX_POSITION)[::-1]
        if addr < ADDR.GOAL_POSITION + 4 and end > ADDR.GOAL_POSITION:
            goal = int(struct.unpack_from("<i", new, ADDR.GOAL_POSITION)[0])
            if not lo <= goal <= hi:
                return Result.DATA_LIMIT
        if addr <= ADDR.TORQUE_ENABLE < end and new[ADDR.TORQUE_ENABLE] > 1:
            return Result.DATA_RANGE
        t[addr:end] = data
        if addr <= ADDR.RETURN_DELAY < end:
            st.return_delay_us = t[ADDR.RETURN_DELAY] * 2
        if addr < ADDR.MIN_POSITION + 4 and end > ADDR.HOMING_OFFSET:
            home = self._homing()
            st.min_steps, st.max_steps = lo - home, hi - home
            st.goal_steps = int(struct.unpack_from("<i", t, ADDR.GOAL_POSITION)[0]) - home
        if addr <= ADDR.TORQUE_ENABLE < end:
            st.torque = bool(t[ADDR.TORQUE_ENABLE]) and not st.fault.stops_torque
        if addr < ADDR.GOAL_POSITION + 4 and end > ADDR.GOAL_POSITION:
            st.goal_steps = int(struct.unpack_from("<i", t, ADDR.GOAL_POSITION)[0]) - self._homing()
        return Result.OK

    def reboot(self) -> None:
        """REBOOT: torque off, the hardware error cleared (it comes back while its condition lasts)."""
        self.state.torque = False
        self.state.fault = Fault.NONE


class DxlRegisterFile:
    """An STS-layout register file (the IMU, the probe) answering Protocol 2.0 at the same addresses."""

    def __init__(self, device: Device) -> None:
        self.device = device

    @property
    def id(self) -> int:
        return self.device.id

    @property
    def model(self) -> int:
        return self.device.model

    @property
    def firmware(self) -> int:
        return self.device.firmware

    @property
    def return_delay_us(self) -> int:
        return self.device.return_delay_us

    @property
    def alert(self) -> bool:
        return False

    def read(self, addr: int, n: int) -> tuple[int, bytes]:
        data = self.device.read(addr, n)
        return (Result.DATA_RANGE, b"") if data is None else (Result.OK, data)

    def write(self, addr: int, data: bytes) -> int:
        if addr < 0 or addr + len(data) > len(self.device.table):
            return Result.DATA_RANGE
        return Result.OK if self.device.write(addr, data) else Result.ACCESS

    def reboot(self) -> None:
        pass

