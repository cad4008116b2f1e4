"""The Feetech SCS/STS packet protocol, device side (pure: bytes in, packets out).

Instruction packet (controller -> devices) and status packet (device -> controller)::

    0xFF 0xFF ID LENGTH INSTRUCTION|ERROR PARAM_1 ... PARAM_N CHECKSUM
    LENGTH = N + 2,  CHECKSUM = ~(ID + LENGTH + INSTRUCTION|ERROR + PARAM_1 + ... + PARAM_N) & 0xFF

Instructions: PING 0x01, READ 0x02 (addr, len), WRITE 0x03 (addr, data...), REG_WRITE 0x04,
ACTION 0x05, SYNC_READ 0x82 (addr, len, id...), SYNC_WRITE 0x83 (addr, len, (id, data...)...).
ID 0xFE is the broadcast id (no status packet, except SYNC READ's per-id answers). Multi-byte
registers of the STS series are little-endian; speed and load carry their sign in a high bit
(sign-magnitude: speed bit 15, load bit 10, as ``scservo_sdk``'s ``SCS_TOHOST``).

Source: Feetech's SCServo SDK (``feetech-servo-sdk`` on PyPI, ``protocol_packet_handler.py``:
``txPacket``/``rxPacket``), which is the controller side; no library implements the servo side,
so this module is written by hand and tested against that SDK (tests/cfirmware).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "BROADCAST_ID",
    "Instruction",
    "InstructionParser",
    "checksum",
    "from_sign_magnitude",
    "instruction_packet",
    "status_packet",
    "to_sign_magnitude",
]

BROADCAST_ID = 0xFE
MAX_LENGTH = 250  # the SDK's TXPACKET_MAX_LEN


class Inst:
    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83


@dataclass(frozen=True)
class Instruction:
    """One instruction packet as received: its id, instruction byte, parameters and wire bytes."""

    id: int
    instruction: int
    params: bytes
    raw: bytes


def checksum(body: bytes) -> int:
    """~(sum of ID, LENGTH, INSTRUCTION/ERROR and the params) & 0xFF."""
    return ~sum(body) & 0xFF


def instruction_packet(dev_id: int, instruction: int, params: bytes = b"") -> bytes:
    body = bytes([dev_id & 0xFF, len(params) + 2, instruction & 0xFF]) + bytes(params)
    return b"\xff\xff" + body + bytes([checksum(body)])


def status_packet(dev_id: int, error: int = 0, params: bytes = b"") -> bytes:
    body = bytes([dev_id & 0xFF, len(params) + 2, error & 0xFF]) + bytes(params)
    return b"\xff\xff" + body + bytes([checksum(body)])


def to_sign_magnitude(v: int, bit: int) -> int:
    """A signed value as the STS registers hold it: magnitude below ``bit``, sign at ``bit``."""
    mag = min(abs(int(v)), (1 << bit) - 1)
    return mag | (1 << bit) if v < 0 else mag


def from_sign_magnitude(raw: int, bit: int) -> int:
    mag = raw & ((1 << bit) - 1)
    return -mag if raw >> bit & 1 else mag


class InstructionParser:
    """Incremental parser of instruction packets; garbage and bad checksums are skipped and counted.

    Holds at most one packet (``MAX_LENGTH`` + 4 bytes) of unparsed input.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.bad_packets = 0
        self.garbage_bytes = 0

    def feed(self, data: bytes) -> list[Instruction]:
        self._buf += data
        out: list[Instruction] = []
        buf = self._buf
        while True:
            start = buf.find(b"\xff\xff")
            if start < 0:
                keep = 1 if buf.endswith(b"\xff") else 0
                self.garbage_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                break
            if start:
                self.garbage_bytes += start
                del buf[:start]
            if len(buf) < 4:
                break
            dev_id, length = buf[2], buf[3]
            if dev_id == 0xFF or length < 2 or length > MAX_LENGTH:
                self.bad_packets += 1
                del buf[:1]
                continue
            total = length + 4
            if len(buf) < total:
                break
            raw = bytes(buf[:total])
            if checksum(raw[2:-1]) != raw[-1]:
                self.bad_packets += 1
                del buf[:1]
                continue
            del buf[:total]
            out.append(Instruction(dev_id, raw[4], raw[5:-1], raw))
        return out
