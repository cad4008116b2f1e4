"""The Dynamixel X-series control table as a view over one servo's :class:`ServoState`.

Layout (little-endian; ``R`` read-only, ``E`` EEPROM: writable only with torque off)::

    0  model number (2, R)      6  firmware version (R)   7  id (E)          8  baud rate (E)
    9  return delay (E, 2 us)  10  drive mode (E)         11 operating mode (E, 3 = position)
    20 homing offset (4, E)    31 temperature limit (E)   32 / 34 max / min voltage limit (2, E, 0.1 V)
    36 PWM limit (2, E)        38 current limit (2, E)    44 velocity limit (4, E, 0.229 rpm)
    48 max position limit (4, E)   52 min position limit (4, E)
    63 shutdown (E: the hardware error bits that turn torque off; XL330 53, XM430 52 as shipped)
    64 torque enable            65 LED                     68 status return level (0..2)
    70 hardware error status (R: bit 0 input voltage, 2 overheating, 3 motor encoder,
       4 electrical shock, 5 overload)
    116 goal position (4)      122 moving (R)             124 present PWM (2, R, signed)
    126 present current (2, R, signed, model's unit)      128 present velocity (4, R, signed, 0.229 rpm)
    132 present position (4, R, signed)  144 present input voltage (2, R, 0.1 V)
    146 present temperature (R, deg C)
    indirect address k (2 each, writable with torque off) -> indirect data k (1 each: reads and
    writes go to the address that indirect address k holds):
        XL330-M288-T (model 1200, the default): addresses 1..20 at 168..207, data at 208..227
        XM430-W350 (model 1020): 1..28 at 168..223, data at 224..251; 29..56 at 578..633, data at 634..661

Errors (the status packet's low 7 bits, :class:`~firmware_sim.plant.dynamixel.Result`): outside the
table -> data range; a write to a read-only address, or to EEPROM / an indirect address with torque
on -> access; a write that splits a multi-byte item -> data length; a goal position outside the
min/max position limits, an indirect address outside the RAM area -> data limit (nothing written).

Sources: ROBOTIS e-Manual control tables, emanual.robotis.com/docs/en/dxl/x/xl330-m288/ and
.../x/xm430-w350/ (source: github.com/ROBOTIS-GIT/emanual, docs/en/dxl/x/*.md); DynamixelSDK's
``indirect_address`` examples ("Indirect address would not accessible when the torque is already
enabled"). Modelled: position mode only (operating mode and drive mode are stored, not acted on);
homing offset is added to present position and subtracted from the goal; the position limits start
at the joint's range (a configured robot), not 0..4095. Present PWM and current are the load
fraction times the PWM and current limits: an approximation.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from firmware_sim.plant.devices import Device
from firmware_sim.plant.dynamixel import Result
from firmware_sim.plant.servo import Fault, ServoState

__all__ = ["ADDR", "DXL_BAUD_CODES", "DxlModel", "DxlRegisterFile", "DxlServo", "HW_ERROR_BITS", "MODELS",
           "MODEL_XL330", "MODEL_XM430", "dxl_model", "hardware_error"]

MODEL_XL330 = 1200
MODEL_XM430 = 1020
FIRMWARE = 52
#: baud rate register value -> bits per second
DXL_BAUD_CODES: dict[int, int] = {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000,
                                  6: 4_000_000, 7: 4_500_000}
#: hardware error status bits of each fault
HW_ERROR_BITS: dict[int, int] = {Fault.VOLTAGE: 0x01, Fault.OVERHEAT: 0x04, Fault.OVERLOAD: 0x20}
RPM_UNIT = 0.229
PWM_LIMIT = 885


@dataclass(frozen=True)
class DxlModel:
    """What differs between the X-series models the plant knows (e-Manual control tables)."""

    number: int
    name: str
    size: int  # the control table's length (bytes)
    indirect: tuple[tuple[int, int, int], ...]  # (indirect address 1's address, indirect data 1's, count) blocks
    temperature_limit: int  # deg C
    max_voltage_dv: int
    min_voltage_dv: int
    nominal_voltage_dv: int
    current_limit: int  # register units
    velocity_limit: int  # 0.229 rpm
    shutdown: int  # Shutdown (63) as shipped: hardware error bits that turn torque off


XL330 = DxlModel(MODEL_XL330, "XL330-M288-T", 228, ((168, 208, 20),), 70, 70, 35, 50, 1750, 445, 53)
XM430 = DxlModel(MODEL_XM430, "XM430-W350", 662, ((168, 224, 28), (578, 634, 28)), 80, 160, 95, 120, 1193, 350, 52)
MODELS: dict[int, DxlModel] = {m.number: m for m in (XL330, XM430)}


def dxl_model(number: int) -> DxlModel:
    """The layout a servo reporting model ``number`` has (an unknown number: the XL330's)."""
    return MODELS.get(number, XL330)


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
    SHUTDOWN = 63
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
    PWM_LIMIT = 36
    CURRENT_LIMIT = 38
    INDIRECT_ADDRESS = 168  # indirect address 1 (both models)
    INDIRECT_DATA_XL330 = 208  # indirect data 1
    INDIRECT_DATA_XM430 = 224


#: (address, size) of every multi-byte item below the indirect area a write must not split
_ITEMS: list[tuple[int, int]] = [
    (0, 2), (2, 4), (20, 4), (24, 4), (32, 2), (34, 2), (36, 2), (38, 2), (40, 4), (44, 4), (48, 4), (52, 4),
    (76, 2), (78, 2), (80, 2), (82, 2), (84, 2), (88, 2), (90, 2), (100, 2), (102, 2), (104, 4), (108, 4),
    (112, 4), (116, 4), (120, 2), (124, 2), (126, 2), (128, 4), (132, 4), (136, 4), (140, 4), (144, 2),
]
_READ_ONLY = frozenset({*range(0, 7), 69, 70, *range(120, 148)})
_BAUD_CODE = {v: k for k, v in DXL_BAUD_CODES.items()}


def hardware_error(fault: int) -> int:
    """The hardware error status register (address 70) for ``fault``."""
    return sum(bit for f, bit in HW_ERROR_BITS.items() if fault & f)


def _shutdown_faults(register: int) -> int:
    """The :class:`Fault` bits a Shutdown register value (address 63, hardware error bits) names."""
    return sum(f for f, bit in HW_ERROR_BITS.items() if register & bit)


class DxlServo:
    """One Dynamixel X servo's control table over ``state``, laid out as its model number says
    (see the module docstring). ``baud``: the bus speed, shown in the baud rate register."""

    def __init__(self, state: ServoState, *, baud: int = 57600) -> None:
        self.state = state
        m = self.spec = dxl_model(state.model)
        t = self.table = bytearray(m.size)
        t[ADDR.FIRMWARE] = FIRMWARE
        t[ADDR.ID] = state.id
        t[ADDR.BAUD] = _BAUD_CODE.get(baud, 1)
        t[ADDR.RETURN_DELAY] = min(254, state.return_delay_us // 2)
        t[ADDR.OPERATING_MODE] = 3
        t[ADDR.TEMPERATURE_LIMIT] = m.temperature_limit
        struct.pack_into("<HHHH", t, ADDR.MAX_VOLTAGE, m.max_voltage_dv, m.min_voltage_dv, PWM_LIMIT, m.current_limit)
        struct.pack_into("<I", t, ADDR.VELOCITY_LIMIT, m.velocity_limit)
        struct.pack_into("<ii", t, ADDR.MAX_POSITION, state.max_steps, state.min_steps)
        t[ADDR.STATUS_RETURN_LEVEL] = 2
        t[ADDR.SHUTDOWN] = m.shutdown
        state.shutdown = _shutdown_faults(m.shutdown)
        struct.pack_into("<i", t, ADDR.GOAL_POSITION, state.goal_steps)
        self._items = list(_ITEMS)
        self._indirect: dict[int, int] = {}  # indirect data address -> its indirect address register
        self._ind_regs: set[int] = set()
        for base, data, count in m.indirect:
            for k in range(count):
                struct.pack_into("<H", t, base + 2 * k, data + k)
                self._items.append((base + 2 * k, 2))
                self._indirect[data + k] = base + 2 * k
                self._ind_regs.update((base + 2 * k, base + 2 * k + 1))
        self._ram_end = m.indirect[-1][1] + m.indirect[-1][2]  # an indirect address may point below this
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

    @property
    def status_return_level(self) -> int:
        """Address 68: 0 answers PING only, 1 also READ, 2 everything."""
        return int(self.table[ADDR.STATUS_RETURN_LEVEL])

    @property
    def indirect_data(self) -> int:
        """Address of indirect data 1 (208 on the XL330, 224 on the XM430)."""
        return self.spec.indirect[0][1]

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
        struct.pack_into("<hhii", t, ADDR.PRESENT_PWM, round(load * PWM_LIMIT), round(load * self.spec.current_limit),
                         int(round(rpm / RPM_UNIT)), st.present_steps + self._homing())
        struct.pack_into("<HB", t, ADDR.PRESENT_VOLTAGE, st.voltage_dv & 0xFFFF, st.temperature_c & 0xFF)

    def _resolve(self, a: int) -> int:
        reg = self._indirect.get(a)
        return a if reg is None else int(struct.unpack_from("<H", self.table, reg)[0])

    def read(self, addr: int, n: int) -> tuple[int, bytes]:
        """(result, data): ``n`` bytes from ``addr`` (data range error outside the table)."""
        t = self.table
        if n < 1 or addr < 0 or addr + n > len(t):
            return Result.DATA_RANGE, b""
        self._render()
        mapped = [self._resolve(a) for a in range(addr, addr + n)]
        if any(not 0 <= a < len(t) for a in mapped):
            return Result.DATA_RANGE, b""
        return Result.OK, bytes(t[a] for a in mapped)

    def write(self, addr: int, data: bytes) -> int:
        """Write ``data`` at ``addr``; returns the result code (:class:`Result`; OK when written).

        Indirect data resolve to their addresses first; the resulting runs of consecutive addresses
        are checked (all of them) before any is written."""
        n = len(data)
        if n < 1 or addr < 0 or addr + n > len(self.table):
            return Result.DATA_RANGE
        runs: list[tuple[int, bytearray]] = []
        for a, b in zip((self._resolve(a) for a in range(addr, addr + n)), data):
            if runs and runs[-1][0] + len(runs[-1][1]) == a:
                runs[-1][1].append(b)
            else:
                runs.append((a, bytearray([b])))
        for a, chunk in runs:
            r = self._check(a, bytes(chunk))
            if r != Result.OK:
                return r
        for a, chunk in runs:
            self._store(a, bytes(chunk))
        return Result.OK

    def _check(self, addr: int, data: bytes) -> int:
        st, t = self.state, self.table
        end = addr + len(data)
        if addr < 0 or end > len(t):
            return Result.DATA_RANGE
        if any(a in _READ_ONLY for a in range(addr, end)):
            return Result.ACCESS
        locked = st.torque and not (addr <= ADDR.TORQUE_ENABLE < end and data[ADDR.TORQUE_ENABLE - addr] == 0)
        if locked and (addr < ADDR.EEPROM_END or any(a in self._ind_regs for a in range(addr, end))):
            return Result.ACCESS
        if any(a < addr < a + n or a < end < a + n for a, n in self._items):
            return Result.DATA_LENGTH
        new = bytearray(t)
        new[addr:end] = data
        hi, lo = struct.unpack_from("<ii", new, ADDR.MAX_POSITION)
        if addr < ADDR.GOAL_POSITION + 4 and end > ADDR.GOAL_POSITION:
            if not lo <= int(struct.unpack_from("<i", new, ADDR.GOAL_POSITION)[0]) <= hi:
                return Result.DATA_LIMIT
        if addr <= ADDR.TORQUE_ENABLE < end and new[ADDR.TORQUE_ENABLE] > 1:
            return Result.DATA_RANGE
        for base, _, count in self.spec.indirect:
            for k in range(count):
                reg = base + 2 * k
                if addr < reg + 2 and end > reg:
                    target = int(struct.unpack_from("<H", new, reg)[0])
                    if not ADDR.EEPROM_END <= target < self._ram_end or target in self._indirect:
                        return Result.DATA_LIMIT
        return Result.OK

    def _store(self, addr: int, data: bytes) -> None:
        st, t = self.state, self.table
        end = addr + len(data)
        t[addr:end] = data
        if addr <= ADDR.RETURN_DELAY < end:
            st.return_delay_us = t[ADDR.RETURN_DELAY] * 2
        if addr < ADDR.MIN_POSITION + 4 and end > ADDR.HOMING_OFFSET:
            hi, lo = struct.unpack_from("<ii", t, ADDR.MAX_POSITION)
            home = self._homing()
            st.min_steps, st.max_steps = lo - home, hi - home
            st.goal_steps = int(struct.unpack_from("<i", t, ADDR.GOAL_POSITION)[0]) - home
        if addr <= ADDR.SHUTDOWN < end:
            st.shutdown = _shutdown_faults(t[ADDR.SHUTDOWN])
        if addr <= ADDR.TORQUE_ENABLE < end:
            st.torque = bool(t[ADDR.TORQUE_ENABLE]) and not st.fault & st.shutdown
        if addr < ADDR.GOAL_POSITION + 4 and end > ADDR.GOAL_POSITION:
            st.goal_steps = int(struct.unpack_from("<i", t, ADDR.GOAL_POSITION)[0]) - self._homing()

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

    @property
    def status_return_level(self) -> int:
        return 2

    def read(self, addr: int, n: int) -> tuple[int, bytes]:
        data = self.device.read(addr, n)
        return (Result.DATA_RANGE, b"") if data is None else (Result.OK, data)

    def write(self, addr: int, data: bytes) -> int:
        if addr < 0 or addr + len(data) > len(self.device.table):
            return Result.DATA_RANGE
        return Result.OK if self.device.write(addr, data) else Result.ACCESS

    def reboot(self) -> None:
        pass

