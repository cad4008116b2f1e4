"""A robot's real servo bus opened with the vendor's own SDK: ``scservo_sdk`` (feetech-servo-sdk) for
Feetech SCS/STS, ``dynamixel_sdk`` for ROBOTIS Dynamixel Protocol 2.0 (X series control table).

Only what calibration needs: ping (the model number), torque off, present position. Every SDK call goes
through :meth:`ServoBus._sdk`: the SDKs trust the bytes they read (a short or garbled status packet that
passes its checksum raises ``IndexError`` and friends from deep inside them), so any exception from a call
counts as a failed attempt, and after :data:`RETRIES` of them it is a :class:`BusError` naming the servo
(id and name). Before each retry a late reply to the failed attempt is let in and dropped (:data:`DRAIN_S`):
a busy machine's late answer would otherwise be read as the next request's, short (the same IndexError). Nothing here writes a servo's EEPROM (its id, offset or angle limits): the calibration lives in the robot package's
``calibration.toml`` and the board applies it (:mod:`robots.hardware`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

from robots.hardware import STEP_MAX, BusProtocol

__all__ = ["BusError", "Registers", "REGISTERS", "ServoBus", "parse_servo_bus"]

RETRIES = 3
#: before a retry, how long a late reply to the failed attempt is given to arrive (then dropped), seconds
DRAIN_S = 0.02
T = TypeVar("T")


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
    """The servos on ``port`` at ``baud`` speaking ``protocol``, through the vendor SDK; ``names``: servo id ->
    name, for the error lines."""

    def __init__(self, port: str, baud: int, protocol: BusProtocol, names: Mapping[int, str] | None = None) -> None:
        self.port_name, self.baud, self.protocol = port, baud, protocol
        self.names = dict(names or {})
        self.last_corrupt = False  # the last failed attempt of the last call got a corrupt reply
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
        self._corrupt = sdk.COMM_RX_CORRUPT  # a reply whose checksum/CRC or header is wrong
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

    def who(self, servo_id: int) -> str:
        name = self.names.get(servo_id)
        return f"servo {servo_id} ({name})" if name else f"servo {servo_id}"

    def _sdk(self, servo_id: int, what: str, call: Callable[[], T]) -> T:
        """``call()`` (one vendor-SDK transaction with servo ``servo_id``); any exception from the SDK (bad
        bytes it did not check: a short reply, two servos answering at once) becomes :class:`BusError`."""
        try:
            return call()
        except Exception as e:  # noqa: BLE001 - whatever the SDK raises on bytes it did not expect
            raise BusError(f"{self.who(servo_id)} answered a {what} with a garbled or short reply "
                           f"({type(e).__name__}: {e}): two servos with this id, noise on the line, or a loose "
                           "cable") from None

    def _attempts(self, servo_id: int, what: str, call: Callable[[], T], ok: Callable[[Any], bool]) -> tuple[T | None, str]:
        """Up to :data:`RETRIES` attempts of ``call``; (the first answer ``ok`` accepts or None, why the last failed).
        A garbled reply is a failed attempt; when every attempt was garbled the :class:`BusError` is raised."""
        why, garbled = "", None
        self.last_corrupt = False
        for attempt in range(RETRIES):
            if attempt:
                self._drain()
            try:
                answer = self._sdk(servo_id, what, call)
            except BusError as e:
                garbled = e
                why = str(e)
                continue
            garbled = None
            if ok(answer):
                return answer, ""
            why = self._result_text(answer)
            self.last_corrupt = self._result(answer) == self._corrupt
        if garbled is not None:
            raise garbled
        return None, why

    def _drain(self) -> None:
        """Before a retry: let a late reply to the failed attempt arrive, then drop it. Read as the answer to
        the next request it would be garbage (a ping's status taken for a register read: the SDK's
        IndexError), and every retry after it one reply behind."""
        time.sleep(DRAIN_S)
        try:
            self._port.clearPort()
        except Exception:  # noqa: BLE001 - the next attempt reports what is wrong with the port
            pass

    @staticmethod
    def _result(answer: Any) -> object:
        return answer[-2] if isinstance(answer, tuple) and len(answer) >= 2 else None

    def _result_text(self, answer: Any) -> str:
        try:
            return str(self._ph.getTxRxResult(self._result(answer)))
        except Exception:  # noqa: BLE001 - only for the message
            return "no valid answer"

    def ping(self, servo_id: int) -> int | None:
        """The model number servo ``servo_id`` reports, None when it does not answer; BusError when it answers
        garbled (a bad checksum, or bytes the SDK chokes on) every time."""
        answer, why = self._attempts(servo_id, "ping", lambda: self._ph.ping(self._port, servo_id),
                                     lambda a: a[1] == self._ok)
        if answer is None and self.last_corrupt:
            raise BusError(f"{self.who(servo_id)} answered a ping with a garbled reply ({why}): two servos with "
                           "this id, noise on the line, or a loose cable")
        return None if answer is None else int(answer[0])

    def torque_off(self, servo_id: int) -> bool:
        """Torque off (the servo goes limp); False when it did not acknowledge; BusError when it answers
        garbled every time."""
        answer, _ = self._attempts(
            servo_id, "torque-off write",
            lambda: self._ph.write1ByteTxRx(self._port, servo_id, self.regs.torque_enable, 0), lambda a: a[0] == self._ok)
        return answer is not None

    def _read_position(self, servo_id: int) -> tuple[int, int, int]:
        if self.regs.position_bytes == 2:
            raw, result, error = self._ph.read2ByteTxRx(self._port, servo_id, self.regs.present_position)
            return (-(raw & 0x7FFF) if raw & 0x8000 else raw), result, error
        raw, result, error = self._ph.read4ByteTxRx(self._port, servo_id, self.regs.present_position)
        return (raw - (1 << 32) if raw & 0x80000000 else raw), result, error

    def position(self, servo_id: int) -> int:
        """Present position register (raw steps, 0..4095); BusError when it does not answer, or garbled."""
        answer, why = self._attempts(servo_id, "present-position read", lambda: self._read_position(servo_id),
                                     lambda a: a[1] == self._ok)
        if answer is None:
            raise BusError(f"{self.who(servo_id)} did not answer a present-position read ({why})")
        value = int(answer[0])
        if not 0 <= value <= STEP_MAX:
            raise BusError(f"{self.who(servo_id)} reports present position {value}, outside 0..{STEP_MAX} "
                           "(a multi-turn or extended position mode? set it to position mode)")
        return value
