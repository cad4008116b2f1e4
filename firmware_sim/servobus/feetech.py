"""Feetech SCS/STS servos (STS3215 class) on Feetech's own SDK, ``scservo_sdk`` (feetech-servo-sdk).

Registers (the STS memory map, as :mod:`firmware_sim.plant.devices`): 3-4 model number, 40 torque
enable, 42-43 goal position (steps), 56-57 present position (steps), 58-59 present speed (steps/s,
sign at bit 15), 60-61 present load (0.1 % of full torque, sign at bit 10). Multi-byte registers
are little-endian (``PacketHandler(0)``).

Per tick: ONE SYNC READ of 56..61 (position, speed, load) whose status packets also carry each
servo's error byte (bit 0 input voltage, 2 overheating, 3 over-current, 5 overload; the SDK's
``ERRBIT_*``), and ONE SYNC WRITE of 42..43.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from firmware_sim.servobus.base import CORRUPT, OVERHEAT, OVERLOAD, TIMEOUT, VOLTAGE, Present
from firmware_sim.servobus.ports import sts_port
from firmware_sim.servobus.sdkbus import Answer, SdkBus

__all__ = ["FeetechBus", "STS_ERRORS"]

MODEL_ADDR = 3
PRESENT_ADDR = 56
PRESENT_BYTES = 6
#: error byte bit -> fault (bit 3, over-current, is an overload as far as the robot goes)
STS_ERRORS: tuple[tuple[int, str], ...] = ((0x01, VOLTAGE), (0x04, OVERHEAT), (0x08, OVERLOAD), (0x20, OVERLOAD))


def _sign_magnitude(raw: int, bit: int) -> int:
    mag = raw & ((1 << bit) - 1)
    return -mag if raw >> bit & 1 else mag


class FeetechBus(SdkBus):
    """STS servos over ``scservo_sdk``."""

    protocol = "sts"
    goal_bytes = 2
    STATUS_BYTES = 6
    TORQUE_ADDR = 40
    GOAL_ADDR = 42

    def _make_port(self) -> Any:
        return sts_port(self.port, self.latency_ms)

    def _make_ph(self) -> Any:
        from scservo_sdk import PacketHandler

        return PacketHandler(0)  # 0: STS byte order (little-endian)

    def _tx(self, dev_id: int, instruction: int, params: list[int]) -> bool:
        from scservo_sdk import COMM_SUCCESS

        pkt = [0, 0, dev_id, len(params) + 2, instruction, *params, 0]
        try:
            return bool(self._ph.txPacket(self._port, pkt) == COMM_SUCCESS)
        except Exception:  # noqa: BLE001 - a vanished adapter
            self._port.is_using = False
            return False

    def _rx(self) -> Answer:
        from scservo_sdk import COMM_RX_TIMEOUT, COMM_SUCCESS

        pkt, result = self._ph.rxPacket(self._port)
        if result == COMM_SUCCESS:
            return int(pkt[2]), int(pkt[4]), [int(b) for b in pkt[5:-1]]
        return TIMEOUT if result == COMM_RX_TIMEOUT else CORRUPT

    def _sync_read_tx(self, addr: int, n: int, ids: list[int]) -> bool:
        from scservo_sdk import COMM_SUCCESS

        try:
            return bool(self._ph.syncReadTx(self._port, addr, n, ids, len(ids)) == COMM_SUCCESS)
        except Exception:  # noqa: BLE001
            self._port.is_using = False
            return False

    def _model_of(self, dev_id: int, ping_params: list[int]) -> int | None:
        self._fresh()
        if not self._tx(dev_id, 2, [MODEL_ADDR, 2]):
            return None
        self._port.setPacketTimeout(self.STATUS_BYTES + 2)
        r = self._answer_from(dev_id)
        if not isinstance(r, tuple) or len(r[2]) < 2:
            return None
        return r[2][0] | r[2][1] << 8

    def _read_spec(self) -> tuple[int, int]:
        return PRESENT_ADDR, PRESENT_BYTES

    def _present(self, dev_id: int, error: int, params: list[int]) -> Present:
        pos = _sign_magnitude(params[0] | params[1] << 8, 15)
        speed = _sign_magnitude(params[2] | params[3] << 8, 15)
        load = _sign_magnitude(params[4] | params[5] << 8, 10) / 1000.0
        errors = tuple(dict.fromkeys(name for bit, name in STS_ERRORS if error & bit))
        return Present(pos, speed, max(-1.0, min(1.0, load)), errors)
