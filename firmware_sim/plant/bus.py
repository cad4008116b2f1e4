"""The plant's side of the servo bus: instructions in, status packets out, bus time modelled.

:class:`PlantBus` answers every instruction packet for the devices of a :class:`World` as the
devices would (PING, READ, WRITE, REG_WRITE + ACTION, SYNC READ, SYNC WRITE; broadcast id 0xFE).
Clock coupling: in **lockstep** a SYNC WRITE that covers the goal-position register advances the
world one control period (the firmware writes the goals exactly once per control tick, in every
mode), so physics runs in the firmware's virtual time; in **realtime** the world steps on the
wall clock (:meth:`PlantBus.next_step_time`) and a goal write only sets the goals.

Bus time at ``baud`` (1 Mbaud, 10 bits per byte): every packet both ways costs its bytes' time,
each status packet also the servo's return delay (register 7, 2 us units; 0 by default). The
accounting is per control period (from one goal write to the next): ``stats()`` gives the mean
and largest bus time per tick and how many ticks needed more than the period. In realtime the
status packets are also released no earlier than their modelled end time.

Faults: ``kill(servo_id, at_us)`` makes a device stop answering from world time ``at_us``
(``--dead-servo ID@SECONDS`` on the board's command line).

Lateness (realtime): the plant tells when it fell behind the wall clock (its process descheduled, a
loaded machine): :class:`PlantLateness` counts the physics steps run later than one period after
they were due, the largest lag (us) and the steps skipped when it re-anchored. A late plant answers
late; it never stops answering (that is the board's to tell apart from a dead servo).
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

from firmware_sim.plant.devices import REG, Device
from firmware_sim.plant.feetech import BROADCAST_ID, Inst, Instruction, InstructionParser, status_packet
from firmware_sim.plant.world import World

__all__ = ["BusStats", "PlantBus", "PlantLateness"]

BYTE_BITS = 10


@dataclass
class BusStats:
    ticks: int = 0
    busy_us_total: float = 0.0
    busy_us_max: float = 0.0
    over_budget: int = 0
    packets_in: int = 0
    packets_out: int = 0

    def line(self, period_us: int) -> str:
        mean = self.busy_us_total / self.ticks if self.ticks else 0.0
        return (f"servo bus: {self.ticks} ticks, bus time per tick mean {mean:.0f} us, max {self.busy_us_max:.0f} us "
                f"of {period_us} us ({self.over_budget} ticks over), {self.packets_in} packets in, {self.packets_out} out")


@dataclass
class PlantLateness:
    """Realtime: how far the plant's physics fell behind the wall clock (counts; times in us)."""

    late_steps: int = 0  # steps run more than one control period after they were due
    behind_max_us: float = 0.0  # largest lag of a step behind its due time
    steps_skipped: int = 0  # steps dropped when re-anchoring after falling far behind (not simulated)
    resyncs: int = 0  # how many times it re-anchored

    def as_dict(self) -> dict[str, int]:
        """``{"plant_late_steps", "plant_behind_max_ms", "plant_steps_skipped", "plant_resyncs"}`` (ints)."""
        return {"plant_late_steps": self.late_steps, "plant_behind_max_ms": int(round(self.behind_max_us / 1000)),
                "plant_steps_skipped": self.steps_skipped, "plant_resyncs": self.resyncs}


class PlantBus:
    """Device side of the bus over a :class:`World`."""

    def __init__(self, world: World, *, lockstep: bool, baud: int = 1_000_000) -> None:
        self.world = world
        self.lockstep = lockstep
        self.byte_us = BYTE_BITS * 1e6 / baud
        self.parser = InstructionParser()
        self.stats = BusStats()
        self._tick_busy = 0.0
        self._booted = False
        self._pending_reg: dict[int, tuple[int, bytes]] = {}
        self._dead: list[tuple[int, int]] = []  # (device id, from world time us)
        self._out: deque[tuple[float, bytes]] = deque()  # realtime: (release time, bytes)
        self._free_at = 0.0
        self.t0 = time.monotonic()
        self.steps_wall = 0
        self.lateness = PlantLateness()

    def kill(self, dev_id: int, at_us: int) -> None:
        self._dead.append((dev_id, at_us))

    def _alive(self, dev: Device) -> bool:
        for dev_id, at in self._dead:
            if dev_id == dev.id and self.world.time_us >= at:
                return False
        return dev.alive

    # -- time -----------------------------------------------------------------------------------
    def _wire(self, n: int) -> float:
        return n * self.byte_us

    def _close_tick(self) -> None:
        if not self._booted:  # the first goal write ends the boot (pings, torque on): not a control tick
            self._booted = True
            self._tick_busy = 0.0
            return
        s = self.stats
        s.ticks += 1
        s.busy_us_total += self._tick_busy
        s.busy_us_max = max(s.busy_us_max, self._tick_busy)
        if self._tick_busy > self.world.period_us:
            s.over_budget += 1
        self._tick_busy = 0.0

    def next_step_time(self) -> float | None:
        """Realtime: monotonic time of the next physics step (None in lockstep)."""
        if self.lockstep:
            return None
        return self.t0 + (self.steps_wall + 1) * self.world.period_us / 1e6

    def step_due(self, now: float) -> int:
        """Realtime: run the physics steps due by ``now`` (at most a few; returns how many ran). Lateness
        (a step run more than a period after it was due, a re-anchoring) is counted in :attr:`lateness`."""
        ran = 0
        period_s = self.world.period_us / 1e6
        while not self.lockstep and now >= self.t0 + (self.steps_wall + 1) * period_s and ran < 5:
            behind_us = (now - (self.t0 + (self.steps_wall + 1) * period_s)) * 1e6
            if behind_us > self.world.period_us:
                self.lateness.late_steps += 1
            self.lateness.behind_max_us = max(self.lateness.behind_max_us, behind_us)
            self.world.step()
            self.steps_wall += 1
            ran += 1
        if not self.lockstep and ran == 5:  # far behind: re-anchor instead of bursting
            anchor = int((now - self.t0) / period_s)
            if anchor > self.steps_wall:
                self.lateness.steps_skipped += anchor - self.steps_wall
                self.lateness.resyncs += 1
            self.steps_wall = anchor
        return ran

    # -- packets --------------------------------------------------------------------------------
    def feed(self, data: bytes, now: float | None = None) -> bytes:
        """Bytes from the controller -> bytes to send back now (lockstep); realtime queues them by time."""
        out = bytearray()
        for ins in self.parser.feed(data):
            self.stats.packets_in += 1
            self._tick_busy += self._wire(len(ins.raw))
            for reply in self._handle(ins):
                self.stats.packets_out += 1
                delay = self.world.devices[reply[2]].table[REG.RETURN_DELAY] * 2 if reply[2] in self.world.devices else 0
                self._tick_busy += delay + self._wire(len(reply))
                if self.lockstep or now is None:
                    out += reply
                else:
                    self._free_at = max(self._free_at, now) + (delay + self._wire(len(reply))) / 1e6
                    self._out.append((self._free_at, reply))
        return bytes(out)

    def ready(self, now: float) -> bytes:
        """Realtime: status packets whose modelled end time has come."""
        out = bytearray()
        while self._out and self._out[0][0] <= now:
            out += self._out.popleft()[1]
        return bytes(out)

    def next_release(self) -> float | None:
        return self._out[0][0] if self._out else None

    def _devices_for(self, dev_id: int) -> list[Device]:
        w = self.world
        if dev_id == BROADCAST_ID:
            return [d for d in w.devices.values() if self._alive(d)]
        d = w.devices.get(dev_id)
        return [d] if d is not None and self._alive(d) else []

    def _handle(self, ins: Instruction) -> list[bytes]:
        p, inst, dev_id = ins.params, ins.instruction, ins.id
        w = self.world
        if inst in (Inst.READ, Inst.SYNC_READ):
            w.refresh_if_stale()
        replies: list[bytes] = []
        if inst == Inst.SYNC_WRITE and dev_id == BROADCAST_ID and len(p) >= 2:
            addr, n = p[0], p[1]
            goal = addr <= REG.GOAL_POSITION < addr + n
            for k in range(2, len(p) - n + 1, n + 1):
                d = w.devices.get(p[k])
                if d is not None and self._alive(d):
                    d.write(addr, bytes(p[k + 1:k + 1 + n]))
            if goal and self.lockstep:
                w.step()
                self._close_tick()
            elif goal:
                self._close_tick()
            return replies
        if inst == Inst.SYNC_READ and dev_id == BROADCAST_ID and len(p) >= 2:
            addr, n = p[0], p[1]
            for sid in p[2:]:
                d = w.devices.get(sid)
                if d is None or not self._alive(d):
                    continue
                data = d.read(addr, n)
                if data is not None:
                    replies.append(status_packet(sid, 0, data))
            return replies
        if inst == Inst.ACTION:
            for d in self._devices_for(dev_id):
                reg = self._pending_reg.pop(d.id, None)
                if reg is not None:
                    d.write(*reg)
            return replies
        for d in self._devices_for(dev_id):
            reply: bytes | None = None
            if inst == Inst.PING:
                reply = status_packet(d.id)
            elif inst == Inst.READ and len(p) == 2:
                data = d.read(p[0], p[1])
                reply = status_packet(d.id, 0, data) if data is not None else None
            elif inst == Inst.WRITE and len(p) >= 2:
                reply = status_packet(d.id, 0 if d.write(p[0], bytes(p[1:])) else 0x08)
            elif inst == Inst.REG_WRITE and len(p) >= 2:
                self._pending_reg[d.id] = (p[0], bytes(p[1:]))
                reply = status_packet(d.id)
            if reply is not None and dev_id != BROADCAST_ID:
                replies.append(reply)
        return replies
