"""Feetech SCS/STS instructions answered by the bus devices (the STS side of :class:`PlantBus`).

PING, READ, WRITE, REG_WRITE + ACTION, SYNC READ, SYNC WRITE; broadcast id 0xFE (no answer, except
SYNC READ's per-id answers). A WRITE the device refuses is answered with error byte 0x08; every
status packet carries the device's condition bits (:func:`firmware_sim.plant.devices.sts_error`).
Source of the packet format: ``scservo_sdk`` ``protocol_packet_handler.py``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from firmware_sim.plant.devices import REG, Device
from firmware_sim.plant.feetech import BROADCAST_ID, Inst, Instruction, InstructionParser, status_packet

__all__ = ["StsHandler"]

Reply = tuple[int, bytes]  # (device id, status packet)


class StsHandler:
    """Answers instructions for ``devices`` (id -> STS register file) while ``alive(device)``."""

    def __init__(self, devices: Mapping[int, Device], alive: Callable[[Device], bool],
                 refresh: Callable[[], None], on_goal: Callable[[], None]) -> None:
        self.devices = devices
        self.alive = alive
        self.refresh = refresh
        self.on_goal = on_goal
        self.parser = InstructionParser()
        self._pending_reg: dict[int, tuple[int, bytes]] = {}

    def _targets(self, dev_id: int) -> list[Device]:
        if dev_id == BROADCAST_ID:
            return [d for d in self.devices.values() if self.alive(d)]
        d = self.devices.get(dev_id)
        return [d] if d is not None and self.alive(d) else []

    def handle(self, ins: Instruction) -> list[Reply]:
        p, inst, dev_id = ins.params, ins.instruction, ins.id
        if inst in (Inst.READ, Inst.SYNC_READ):
            self.refresh()
        replies: list[Reply] = []
        if inst == Inst.SYNC_WRITE and dev_id == BROADCAST_ID and len(p) >= 2:
            addr, n = p[0], p[1]
            for k in range(2, len(p) - n + 1, n + 1):
                d = self.devices.get(p[k])
                if d is not None and self.alive(d):
                    d.write(addr, bytes(p[k + 1:k + 1 + n]))
            if addr <= REG.GOAL_POSITION < addr + n:
                self.on_goal()
            return replies
        if inst == Inst.SYNC_READ and dev_id == BROADCAST_ID and len(p) >= 2:
            addr, n = p[0], p[1]
            for sid in p[2:]:
                d = self.devices.get(sid)
                if d is None or not self.alive(d):
                    continue
                data = d.read(addr, n)
                if data is not None:
                    replies.append((sid, status_packet(sid, d.error, data)))
            return replies
        if inst == Inst.ACTION:
            for d in self._targets(dev_id):
                reg = self._pending_reg.pop(d.id, None)
                if reg is not None:
                    d.write(*reg)
            return replies
        for d in self._targets(dev_id):
            reply: bytes | None = None
            if inst == Inst.PING:
                reply = status_packet(d.id, d.error)
            elif inst == Inst.READ and len(p) == 2:
                data = d.read(p[0], p[1])
                reply = status_packet(d.id, d.error, data) if data is not None else None
            elif inst == Inst.WRITE and len(p) >= 2:
                reply = status_packet(d.id, d.error if d.write(p[0], bytes(p[1:])) else 0x08 | d.error)
            elif inst == Inst.REG_WRITE and len(p) >= 2:
                self._pending_reg[d.id] = (p[0], bytes(p[1:]))
                reply = status_packet(d.id, d.error)
            if reply is not None and dev_id != BROADCAST_ID:
                replies.append((d.id, reply))
        return replies
