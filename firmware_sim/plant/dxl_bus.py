"""Dynamixel Protocol 2.0 instructions answered by the bus devices (the DXL side of :class:`PlantBus`).

PING (status data: model number LE16, firmware version; broadcast: every device answers, id
order), READ, WRITE, REG_WRITE + ACTION, REBOOT, SYNC READ / FAST SYNC READ / SYNC WRITE (start address LE16, data
length LE16, ids / (id, data)...), BULK READ (id, address LE16, length LE16)..., BULK WRITE (id,
address LE16, length LE16, data)... SYNC and BULK READ are answered by the listed devices in the
listed order; SYNC and BULK WRITE and broadcast WRITE have no answer. Status return level
(address 68 of a servo): 0 answers PING only, 1 PING and READ, 2 everything. An unknown
instruction is answered with the instruction error; a packet of the wrong size with the data
length error. ACTION is not answered (the SDK does not wait for it). Every status packet's
error byte carries the alert bit while the device's hardware error status is non-zero.

Sources: ``dynamixel_sdk/protocol2_packet_handler.py`` (``syncReadTx``, ``syncWriteTxOnly``,
``bulkReadTx``, ``bulkWriteTxOnly``, ``broadcastPing``, ``readRx``), ``group_sync_read.py``,
``group_bulk_read.py`` and the e-Manual "Protocol 2.0" instruction pages.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Mapping
from typing import Protocol

from firmware_sim.plant.dxl_table import ADDR
from firmware_sim.plant.dynamixel import (
    BROADCAST_ID, ERR_ALERT, DxlInst, DxlInstruction, DxlParser, Result, crc16, status_packet,
)

__all__ = ["DxlDevice", "DxlHandler"]

Reply = tuple[int, bytes]  # (device id, status packet)


class DxlDevice(Protocol):
    """What a device on a Protocol 2.0 bus offers (:class:`~firmware_sim.plant.dxl_table.DxlServo`,
    :class:`~firmware_sim.plant.dxl_table.DxlRegisterFile`)."""

    @property
    def id(self) -> int: ...
    @property
    def model(self) -> int: ...
    @property
    def firmware(self) -> int: ...
    @property
    def return_delay_us(self) -> int: ...
    @property
    def alert(self) -> bool: ...
    @property
    def status_return_level(self) -> int: ...
    def read(self, addr: int, n: int) -> tuple[int, bytes]: ...
    def write(self, addr: int, data: bytes) -> int: ...
    def reboot(self) -> None: ...


class DxlHandler:
    """Answers instructions for ``devices`` (id -> Protocol 2.0 device) while ``alive(device)``."""

    def __init__(self, devices: Mapping[int, DxlDevice], alive: Callable[[DxlDevice], bool],
                 refresh: Callable[[], None], on_goal: Callable[[], None]) -> None:
        self.devices = devices
        self.alive = alive
        self.refresh = refresh
        self.on_goal = on_goal
        self.parser = DxlParser()
        self._pending_reg: dict[int, tuple[int, bytes]] = {}

    def _get(self, dev_id: int) -> DxlDevice | None:
        d = self.devices.get(dev_id)
        return d if d is not None and self.alive(d) else None

    @staticmethod
    def _status(d: DxlDevice, result: int, data: bytes = b"") -> Reply:
        return d.id, status_packet(d.id, result | (ERR_ALERT if d.alert else 0), data)

    def handle(self, ins: DxlInstruction) -> list[Reply]:
        p, inst, dev_id = ins.params, ins.instruction, ins.id
        if inst in (DxlInst.READ, DxlInst.SYNC_READ, DxlInst.FAST_SYNC_READ, DxlInst.BULK_READ):
            self.refresh()
        if dev_id == BROADCAST_ID:
            return self._broadcast(inst, p)
        d = self._get(dev_id)
        if d is None:
            return []
        level = d.status_return_level
        reply: Reply | None
        if inst == DxlInst.PING:
            return [self._status(d, Result.OK, struct.pack("<HB", d.model & 0xFFFF, d.firmware & 0xFF))]
        if inst == DxlInst.READ:
            if len(p) != 4:
                reply = self._status(d, Result.DATA_LENGTH)
            else:
                addr, n = struct.unpack("<HH", p)
                result, data = d.read(addr, n)
                reply = self._status(d, result, data)
            return [reply] if level >= 1 else []
        if inst == DxlInst.WRITE:
            reply = self._status(d, Result.DATA_LENGTH if len(p) < 3 else d.write(p[0] | p[1] << 8, bytes(p[2:])))
        elif inst == DxlInst.REG_WRITE:
            if len(p) < 3:
                reply = self._status(d, Result.DATA_LENGTH)
            else:
                self._pending_reg[d.id] = (p[0] | p[1] << 8, bytes(p[2:]))
                reply = self._status(d, Result.OK)
        elif inst == DxlInst.ACTION:
            self._action([d])
            return []
        elif inst == DxlInst.REBOOT:  # the status is sent before the restart: it still carries the alert
            reply = self._status(d, Result.OK)
            d.reboot()
        else:
            reply = self._status(d, Result.INSTRUCTION)
        return [reply] if level >= 2 else []

    def _action(self, devices: list[DxlDevice]) -> None:
        for d in devices:
            reg = self._pending_reg.pop(d.id, None)
            if reg is not None:
                d.write(*reg)

    def _fast_sync_read(self, p: bytes) -> list[Reply]:
        """FAST SYNC READ: one status packet (id 0xFE) the listed devices fill in turn, each part
        ``ERR ID DATA CRC_L CRC_H`` with the CRC of the packet so far (the last one is the packet's).
        Not byte-stuffed (the SDK's ``rxPacket(fast_option=True)`` does not unstuff). A listed device
        that is not there breaks the chain: the packet ends where it would have answered."""
        addr, n = struct.unpack_from("<HH", p)
        ids = list(p[4:])
        pkt = bytearray(b"\xff\xff\xfd\x00\xfe" + struct.pack("<H", 1 + (n + 4) * len(ids)) + bytes([0x55]))
        first: int | None = None
        for sid in ids:
            d = self._get(sid)
            if d is None:
                break
            result, data = d.read(addr, n)
            pkt += bytes([result | (ERR_ALERT if d.alert else 0), sid]) + (data if result == Result.OK else bytes(n))
            pkt += struct.pack("<H", crc16(bytes(pkt)))
            first = sid if first is None else first
        return [] if first is None else [(first, bytes(pkt))]

    def _broadcast(self, inst: int, p: bytes) -> list[Reply]:
        replies: list[Reply] = []
        if inst == DxlInst.PING:
            for sid in sorted(self.devices):
                d = self._get(sid)
                if d is not None:
                    replies.append(self._status(d, Result.OK, struct.pack("<HB", d.model & 0xFFFF, d.firmware & 0xFF)))
        elif inst == DxlInst.ACTION:
            self._action([d for d in self.devices.values() if self.alive(d)])
        elif inst == DxlInst.WRITE and len(p) >= 3:
            for d in self.devices.values():
                if self.alive(d):
                    d.write(p[0] | p[1] << 8, bytes(p[2:]))
        elif inst == DxlInst.FAST_SYNC_READ and len(p) >= 4:
            replies.extend(self._fast_sync_read(p))
        elif inst in (DxlInst.SYNC_READ, DxlInst.SYNC_WRITE) and len(p) >= 4:
            addr, n = struct.unpack_from("<HH", p)
            if inst == DxlInst.SYNC_READ:
                for sid in p[4:]:
                    d = self._get(sid)
                    if d is not None:
                        result, data = d.read(addr, n)
                        replies.append(self._status(d, result, data))
            else:
                for k in range(4, len(p) - n + 1 if n else 4, n + 1):
                    d = self._get(p[k])
                    if d is not None:
                        d.write(addr, bytes(p[k + 1:k + 1 + n]))
                if addr < ADDR.GOAL_POSITION + 4 and addr + n > ADDR.GOAL_POSITION:
                    self.on_goal()
        elif inst == DxlInst.BULK_READ:
            for k in range(0, len(p) - 4, 5):
                sid, addr, n = struct.unpack_from("<BHH", p, k)
                d = self._get(sid)
                if d is not None:
                    result, data = d.read(addr, n)
                    replies.append(self._status(d, result, data))
        elif inst == DxlInst.BULK_WRITE:
            k = 0
            while k + 5 <= len(p):
                sid, addr, n = struct.unpack_from("<BHH", p, k)
                d = self._get(sid)
                if d is not None:
                    d.write(addr, bytes(p[k + 5:k + 5 + n]))
                k += 5 + n
        return replies
