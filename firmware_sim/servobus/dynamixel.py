"""ROBOTIS Dynamixel X-series servos, Protocol 2.0, on ROBOTIS' own SDK (``dynamixel_sdk``).

X-series control table (e-Manual): 0-1 model number (the ping's answer carries it too), 64 torque
enable, 70 hardware error status (bit 0 input voltage, 2 overheating, 3 motor encoder, 4 electrical
shock, 5 overload), 116-119 goal position (steps, signed), 126-127 present current (signed), 128-131
present velocity (0.229 rpm units, signed), 132-135 present position (steps, signed), 168.. indirect
addresses (2 bytes each); their indirect data at 208.. on the 330 series (XL330/XC330: 20 of them),
224.. on the 430/540 series (:func:`indirect_data_address`).

Per tick: ONE SYNC READ and ONE SYNC WRITE (116, 4 bytes). At start-up (:meth:`DynamixelBus.prepare`)
the indirect addresses 1..11 of every servo are pointed at 70, 126..135 so the sync read of
the 11 indirect data bytes brings the hardware error status with the present values. A servo table that does not
take them (the write refused, or the read-back disagreeing with a direct read of the position)
falls back to the contiguous 126..135 and reads 70 only from a servo whose status packet raises
its alert bit (bit 7 of the error byte): one extra READ on the tick an error appears.

Load: present current over :data:`CURRENT_FULL` units (an XL330's 1750 mA current limit at 1 mA a
unit), an estimate of the fraction of full torque (XM servos count 2.69 mA a unit).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from firmware_sim.servobus.base import CORRUPT, OVERHEAT, OVERLOAD, TIMEOUT, VOLTAGE, Present
from firmware_sim.servobus.ports import dxl_port
from firmware_sim.servobus.sdkbus import Answer, SdkBus

__all__ = ["CURRENT_FULL", "DXL_ERRORS", "DynamixelBus", "INDIRECT"]

HW_ERROR_ADDR = 70
PRESENT_ADDR = 126  # current, velocity, position: 10 bytes
PRESENT_BYTES = 10
INDIRECT_ADDR = 168
INDIRECT_DATA = 224
#: model numbers of the 330 series (XL330-M077/M288, XC330-T181/T288/M181/M288): indirect data at 208
SERIES_330 = frozenset({1190, 1200, 1210, 1220, 1230, 1240})


def indirect_data_address(model: int) -> int:
    """Address of indirect data 1 on a servo of ``model`` (208 on the 330 series, else 224)."""
    return 208 if model in SERIES_330 else INDIRECT_DATA

#: what the indirect addresses 1..11 point at: hardware error status, then 126..135
INDIRECT: tuple[int, ...] = (HW_ERROR_ADDR, *range(PRESENT_ADDR, PRESENT_ADDR + PRESENT_BYTES))
ERR_ALERT = 0x80
CURRENT_FULL = 1750.0
#: velocity unit in steps/s: 0.229 rpm * 4096 steps / 60 s
VELOCITY_STEPS_S = 0.229 * 4096 / 60
#: hardware error status bit -> fault (electrical shock counts as a voltage problem)
DXL_ERRORS: tuple[tuple[int, str], ...] = ((0x01, VOLTAGE), (0x04, OVERHEAT), (0x10, VOLTAGE), (0x20, OVERLOAD))


def _s(v: int, bits: int) -> int:
    return v - (1 << bits) if v >> (bits - 1) & 1 else v


def _le(b: Sequence[int]) -> int:
    return sum(int(x) << (8 * k) for k, x in enumerate(b))


class DynamixelBus(SdkBus):
    """X-series servos over ``dynamixel_sdk`` Protocol 2.0."""

    protocol = "dxl2"
    goal_bytes = 4
    default_return_delay_us = 500.0
    STATUS_BYTES = 11
    TORQUE_ADDR = 64
    GOAL_ADDR = 116
    RETURN_DELAY_ADDR = 9
    ADDR_BYTES = 2
    #: True once every servo's indirect addresses point at :data:`INDIRECT` (``prepare``)
    indirect = False
    #: the indirect data address of the sync read (all servos alike; ``prepare``)
    indirect_data = INDIRECT_DATA

    def ping(self, servo_id: int) -> Any:
        ans = super().ping(servo_id)
        if ans.model is not None:
            self.models[servo_id] = ans.model
        return ans

    def _make_port(self) -> Any:
        return dxl_port(self.port, self.latency_ms)

    def _make_ph(self) -> Any:
        from dynamixel_sdk import PacketHandler

        return PacketHandler(2.0)

    def _tx(self, dev_id: int, instruction: int, params: list[int]) -> bool:
        from dynamixel_sdk import COMM_SUCCESS

        n = len(params) + 3
        pkt = [0, 0, 0, 0, dev_id, n & 0xFF, n >> 8, instruction, *params, 0, 0]
        try:
            return bool(self._ph.txPacket(self._port, pkt) == COMM_SUCCESS)
        except Exception:  # noqa: BLE001 - a vanished adapter
            self._port.is_using = False
            return False

    def _rx(self) -> Answer:
        from dynamixel_sdk import COMM_RX_TIMEOUT, COMM_SUCCESS

        pkt, result = self._ph.rxPacket(self._port, False)
        if result == COMM_SUCCESS:
            return int(pkt[4]), int(pkt[8]), [int(b) for b in pkt[9:-2]]
        return TIMEOUT if result == COMM_RX_TIMEOUT else CORRUPT

    def _sync_read_tx(self, addr: int, n: int, ids: list[int]) -> bool:
        from dynamixel_sdk import COMM_SUCCESS

        try:
            return bool(self._ph.syncReadTx(self._port, addr, n, ids, len(ids), False) == COMM_SUCCESS)
        except Exception:  # noqa: BLE001
            self._port.is_using = False
            return False

    def _model_of(self, dev_id: int, ping_params: list[int]) -> int | None:
        return ping_params[0] | ping_params[1] << 8 if len(ping_params) >= 2 else None

    def _read_spec(self) -> tuple[int, int]:
        return (self.indirect_data, len(INDIRECT)) if self.indirect else (PRESENT_ADDR, PRESENT_BYTES)

    def prepare(self, ids: Sequence[int]) -> bool:
        """Point every servo's indirect addresses at :data:`INDIRECT` (torque must be off); True when all
        took them and read back right, else the contiguous read stays (see the module doc)."""
        table = [b for a in INDIRECT for b in (a & 0xFF, a >> 8)]
        data = {indirect_data_address(self.models.get(i, 0)) for i in ids}
        if len(data) != 1:  # 330s and 430s on one bus: no one address for the sync read
            return False
        at = data.pop()
        for i in ids:
            r = self._request(i, 3, [INDIRECT_ADDR & 0xFF, INDIRECT_ADDR >> 8, *table], 0)
            if not isinstance(r, tuple) or r[1] & 0x7F:
                return False
            via = self._request(i, 2, [at & 0xFF, at >> 8, len(INDIRECT), 0], len(INDIRECT))
            direct = self._request(i, 2, [132, 0, 4, 0], 4)
            if not isinstance(via, tuple) or not isinstance(direct, tuple) or len(via[2]) < len(INDIRECT) \
                    or len(direct[2]) < 4 or abs(_s(_le(via[2][7:11]), 32) - _s(_le(direct[2][:4]), 32)) > 16:
                return False
        self.indirect, self.indirect_data = True, at
        return True

    def _present(self, dev_id: int, error: int, params: list[int]) -> Present:
        if self.indirect:
            hw, params = params[0], params[1:]
        else:
            hw = 0
            if error & ERR_ALERT:  # only then: the hardware error status in one more READ
                r = self._request(dev_id, 2, [HW_ERROR_ADDR, 0, 1, 0], 1)
                hw = r[2][0] if isinstance(r, tuple) and r[2] else 0
        current = _s(_le(params[0:2]), 16)
        velocity = _s(_le(params[2:6]), 32)
        position = _s(_le(params[6:10]), 32)
        errors = tuple(dict.fromkeys(name for bit, name in DXL_ERRORS if hw & bit))
        return Present(position, int(round(velocity * VELOCITY_STEPS_S)), max(-1.0, min(1.0, current / CURRENT_FULL)),
                       errors)
