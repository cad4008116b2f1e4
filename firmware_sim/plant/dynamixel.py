"""ROBOTIS Dynamixel Protocol 2.0, device side (pure: bytes in, packets out).

Instruction packet (controller -> devices) and status packet (device -> controller)::

    0xFF 0xFF 0xFD 0x00 ID LEN_L LEN_H INSTRUCTION PARAM_1 ... PARAM_N CRC_L CRC_H
    LEN = N + 3 (instruction + params + CRC, counted after byte stuffing)
    status: INSTRUCTION = 0x55, PARAM_1 = ERROR, then the data

CRC: CRC-16 over every byte from the header to the last parameter (stuffed, as sent), polynomial
0x8005, initial value 0, not reflected, no final XOR (CRC-16/BUYPASS; ``crcmod``'s
``crc-16-buypass``). Byte stuffing: wherever ``FF FF FD`` occurs in the instruction/parameter
region the sender inserts ``FD`` after it (``FF FF FD FD``) so no header appears inside a packet;
the receiver removes it. Multi-byte fields are little-endian. ID 0xFE is the broadcast id.

Status error byte: bit 7 (:data:`ERR_ALERT`) = the device's Hardware Error Status is non-zero; the
low 7 bits are the result of this instruction (:class:`Result`).

Sources: ROBOTIS DynamixelSDK ``dynamixel_sdk/protocol2_packet_handler.py`` (``txPacket``,
``rxPacket``, ``addStuffing``, ``removeStuffing``, ``updateCRC``, the ``ERRNUM_*`` constants) and
the e-Manual "Protocol 2.0" page (emanual.robotis.com/docs/en/dxl/protocol2/). The SDK is the
controller side; this module is the devices' side, tested with that SDK as the client (tests/plant).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import crcmod.predefined

__all__ = [
    "BROADCAST_ID",
    "DxlInst",
    "DxlInstruction",
    "DxlParser",
    "ERR_ALERT",
    "Result",
    "STATUS",
    "crc16",
    "instruction_packet",
    "status_packet",
    "stuff",
    "unstuff",
]

BROADCAST_ID = 0xFE
HEADER = b"\xff\xff\xfd\x00"
STATUS = 0x55  # the instruction byte of a status packet
ERR_ALERT = 0x80
#: the largest LEN accepted (the SDK's RXPACKET_MAX_LEN / TXPACKET_MAX_LEN is 1000 bytes a packet)
MAX_LENGTH = 1000
#: unparsed input held at most (one largest packet)
MAX_BUFFER = MAX_LENGTH + 7

crc16 = crcmod.predefined.mkCrcFun("crc-16-buypass")
"""CRC-16/BUYPASS of ``bytes`` -> int (0..0xFFFF), what the SDK's ``updateCRC(0, ...)`` computes."""


class DxlInst:
    """Instruction bytes (e-Manual Protocol 2.0, "Instruction")."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    FAST_SYNC_READ = 0x8A
    BULK_READ = 0x92
    BULK_WRITE = 0x93
    FAST_BULK_READ = 0x9A


class Result:
    """The low 7 bits of a status packet's error byte (the SDK's ``ERRNUM_*``)."""

    OK = 0
    RESULT_FAIL = 1
    INSTRUCTION = 2
    CRC = 3
    DATA_RANGE = 4
    DATA_LENGTH = 5
    DATA_LIMIT = 6
    ACCESS = 7


@dataclass(frozen=True)
class DxlInstruction:
    """One instruction packet as received: id, instruction byte, unstuffed parameters, wire bytes."""

    id: int
    instruction: int
    params: bytes
    raw: bytes


def stuff(region: bytes) -> bytes:
    """Insert ``FD`` after every ``FF FF FD`` in the instruction/parameter ``region`` (as the SDK's
    ``addStuffing``; its look-back into ``LEN_L LEN_H`` can never match, LEN <= 1000)."""
    out = bytearray()
    for b in region:
        out.append(b)
        if b == 0xFD and out[-3:] == b"\xff\xff\xfd":
            out.append(0xFD)
    return bytes(out)


def unstuff(region: bytes) -> bytes:
    """Remove the ``FD`` inserted after every ``FF FF FD`` (``FF FF FD FD`` -> ``FF FF FD``)."""
    out = bytearray()
    i = 0
    while i < len(region):
        b = region[i]
        out.append(b)
        if b == 0xFD and i + 1 < len(region) and region[i + 1] == 0xFD and out[-3:] == b"\xff\xff\xfd":
            i += 1  # skip the stuffed FD
        i += 1
    return bytes(out)


def _packet(dev_id: int, instruction: int, params: bytes) -> bytes:
    body = stuff(bytes([instruction & 0xFF]) + bytes(params))
    head = HEADER + bytes([dev_id & 0xFF]) + struct.pack("<H", len(body) + 2)
    pkt = head + body
    return pkt + struct.pack("<H", crc16(pkt))


def instruction_packet(dev_id: int, instruction: int, params: bytes = b"") -> bytes:
    """A complete, stuffed instruction packet."""
    return _packet(dev_id, instruction, params)


def status_packet(dev_id: int, error: int = 0, params: bytes = b"") -> bytes:
    """A complete, stuffed status packet (instruction 0x55, ``error``, ``params``)."""
    return _packet(dev_id, STATUS, bytes([error & 0xFF]) + bytes(params))


class DxlParser:
    """Incremental parser of instruction packets from a byte stream.

    Garbage before a header is skipped (:attr:`garbage_bytes`); a header with an impossible length
    or a bad CRC is dropped one byte at a time (:attr:`bad_packets`, :attr:`bad_crc`). At most
    :data:`MAX_BUFFER` bytes of unparsed input are held (a partial packet waiting for its tail).
    Status packets (instruction 0x55: another device's answer on the shared line) are skipped.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.bad_packets = 0
        self.bad_crc = 0
        self.garbage_bytes = 0

    def feed(self, data: bytes) -> list[DxlInstruction]:
        self._buf += data
        out: list[DxlInstruction] = []
        buf = self._buf
        while True:
            start = buf.find(HEADER[:3])
            if start < 0:
                keep = 2 if buf.endswith(b"\xff\xff") else 1 if buf.endswith(b"\xff") else 0
                self.garbage_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                break
            if start:
                self.garbage_bytes += start
                del buf[:start]
            if len(buf) < 8:
                break
            length = buf[5] | buf[6] << 8
            if buf[3] != 0x00 or buf[4] == 0xFF or buf[4] == 0xFD or length < 3 or length > MAX_LENGTH:
                self.bad_packets += 1
                del buf[:1]
                continue
            total = length + 7
            if len(buf) < total:
                break
            raw = bytes(buf[:total])
            if crc16(raw[:-2]) != raw[-2] | raw[-1] << 8:
                self.bad_crc += 1
                self.bad_packets += 1
                del buf[:1]
                continue
            del buf[:total]
            body = unstuff(raw[7:-2])
            if body[0] == STATUS:
                continue
            out.append(DxlInstruction(raw[4], body[0], body[1:], raw))
        if len(buf) > MAX_BUFFER:  # cannot happen with MAX_LENGTH checked; kept as the bound
            self.garbage_bytes += len(buf) - MAX_BUFFER
            del buf[: len(buf) - MAX_BUFFER]
        return out
