"""A robot's real servo bus opened with the vendor's own SDK: ``scservo_sdk`` (feetech-servo-sdk) for
Feetech SCS/STS, ``dynamixel_sdk`` for ROBOTIS Dynamixel Protocol 2.0 (X series control table).

Only what calibration needs: ping (the model number), torque off, present position. Nothing here
writes a servo's EEPROM (its id, offset or angle limits): the calibration lives in the robot package's
``calibration.toml`` and the board applies it (:mod:`robots.hardware`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from robots.hardware import STEP_MAX, BusProtocol

__all__ = ["BusError", "Registers", "REGISTERS", "ServoBus", "parse_servo_bus"]

RETRIES = 3


class BusError(Exception):
    """The bus cannot be opened or a servo did not answer (the message says which)."""


@dataclass(frozen=True)
class Registers:
    torque_enable: int
    present_position: int
    position_bytes: int  # 2: STS (sign-magnitude at bit 15), 4: Dynamixel (signed 32 bit)


REGISTERS: dict[str, Registers] = {
    "sts": Registers(torque_enable=40, present_position=56, position_bytes=2),   # STS3215 memory map
    "dxl2": Registers(torque_enable=64, present_position=132, position_bytes=4),  # X series (XL330, XM430, ...)
}


def parse_servo_bus(text: str) -> tuple[str, int | None]:
    """``PORT[:BAUD]`` -> (port, baud or None); ValueError says why."""
    port, baud = text, None
    head, sep, tail = text.rpartition(":")
    if sep and tail.isdigit():  # else the whole text is the port (a /dev/serial/by-path name has colons)
        port, baud = head, int(tail)
        if not 9600 <= baud <= 4_500_000:
            raise ValueError(f"{text}: baud {baud} is outside 9600..4500000")
    if not port:
        raise ValueError(f"{text!r}: no port (PORT[:BAUD], e.g. /dev/ttyUSB0:1000000)")
    return port, baud


class ServoBus:
    """The servos on ``port`` at ``baud`` speaking ``protocol``, through the vendor SDK."""

    def __init__(self, port: str, baud: int, protocol: BusProtocol) -> None:
        self.port_name, self.baud, self.protocol = port, baud, protocol
        self.regs = REGISTERS[protocol]
        if protocol == "sts":
            import scservo_sdk as sdk

            self._port: Any = sdk.PortHandler(port)
            self._ph: Any = sdk.PacketHandler(0)  # 0: STS byte order (little-endian)
        else:
            import dynamixel_sdk as sdk  # type: ignore[no-redef]

            self._port = sdk.PortHandler(port)
            self._ph = sdk.PacketHandler(2.0)
        self._ok = sdk.COMM_SUCCESS
        self._open = False

    def open(self) -> None:
        try:
            opened = bool(self._port.openPort())
        except Exception as e:  # serial.SerialException, OSError: no such port, permission
            raise BusError(f"{self.port_name}: cannot open the servo bus ({e})") from None
        if not opened:
            raise BusError(f"{self.port_name}: cannot open the servo bus")
        self._open = True
        try:
            ok = bool(self._port.setBaudRate(self.baud))
        except Exception as e:
            self.close()
            raise BusError(f"{self.port_name}: cannot set {self.baud} baud ({e})") from None
        if not ok:
            self.close()
            raise BusError(f"{self.port_name}: {self.baud} baud is not supported by this port")

    def close(self) -> None:
        if self._open:
            self._open = False
            try:
                self._port.closePort()
            except Exception:
                pass

    def __enter__(self) -> ServoBus:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def ping(self, servo_id: int) -> int | None:
        """The model number servo ``servo_id`` reports, None when it does not answer."""
        for _ in range(RETRIES):
            model, result, _error = self._ph.ping(self._port, servo_id)
            if result == self._ok:
                return int(model)
        return None

    def torque_off(self, servo_id: int) -> bool:
        """Torque off (the servo goes limp); False when it did not acknowledge."""
        for _ in range(RETRIES):
            result, _error = self._ph.write1ByteTxRx(self._port, servo_id, self.regs.torque_enable, 0)
            if result == self._ok:
                return True
        return False

    def position(self, servo_id: int) -> int:
        """Present position register (raw steps, 0..4095); BusError when it does not answer."""
        why = ""
        for _ in range(RETRIES):
            if self.regs.position_bytes == 2:
                raw, result, _error = self._ph.read2ByteTxRx(self._port, servo_id, self.regs.present_position)
                value = -(raw & 0x7FFF) if raw & 0x8000 else raw
            else:
                raw, result, _error = self._ph.read4ByteTxRx(self._port, servo_id, self.regs.present_position)
                value = raw - (1 << 32) if raw & 0x80000000 else raw
            if result == self._ok:
                if not 0 <= value <= STEP_MAX:
                    raise BusError(f"servo {servo_id} reports present position {value}, outside 0..{STEP_MAX} "
                                   "(a multi-turn or extended position mode? set it to position mode)")
                return int(value)
            why = str(self._ph.getTxRxResult(result))
        raise BusError(f"servo {servo_id} did not answer a present-position read ({why})")
