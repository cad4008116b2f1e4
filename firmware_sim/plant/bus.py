"""The plant's side of the servo bus: instructions in, status packets out, bus time modelled.

:class:`PlantBus` answers every instruction packet for the devices of a :class:`World` as the
devices would, in Feetech STS (:mod:`firmware_sim.plant.sts_bus`) or Dynamixel Protocol 2.0
(:mod:`firmware_sim.plant.dxl_bus`), over the protocol's control-table views of the world's
protocol-neutral servo states.

Clock coupling: in **lockstep** a SYNC WRITE that covers the goal-position register advances the
world one control period (the firmware writes the goals exactly once per control tick, in every
mode), so physics runs in the firmware's virtual time; in **realtime** the world steps on the
wall clock (:meth:`PlantBus.next_step_time`) and a goal write only sets the goals.

Bus time at ``baud`` (10 bits per byte): every packet both ways costs its bytes' time, each status
packet also the servo's return delay (STS register 7, 0 by default; DXL address 9, 500 us as
shipped; 2 us units). The
accounting is per control period (from one goal write to the next): ``stats()`` gives the mean
and largest bus time per tick and how many ticks needed more than the period. In realtime the
status packets are also released no earlier than their modelled end time.

Faults: ``kill(servo_id, at_us)`` makes a device stop answering from world time ``at_us``
(``--dead-servo ID@SECONDS`` on the board's command line); the wire-side injected conditions of
``world.conditions`` (missing, duplicate, corrupt) and a controller at another line speed
(``line_baud``) are applied here.

Lateness (realtime): the plant tells when it fell behind the wall clock (its process descheduled, a
loaded machine): :class:`PlantLateness` counts the physics steps run later than one period after
they were due, the largest lag (us) and the steps skipped when it re-anchored. A late plant answers
late; it never stops answering (that is the board's to tell apart from a dead servo).
"""

from __future__ import annotations

import random
import time
from collections import deque
from dataclasses import dataclass

from firmware_sim.plant.collide import collide
from firmware_sim.plant.devices import Device, ServoDevice
from firmware_sim.plant.dxl_bus import DxlDevice, DxlHandler
from firmware_sim.plant.dxl_table import MODEL_XL330, DxlRegisterFile, DxlServo, dxl_model
from firmware_sim.plant.servo import Fault
from firmware_sim.plant.sts_bus import StsHandler
from firmware_sim.plant.world import World

__all__ = ["BusStats", "PROTOCOLS", "PlantBus", "PlantLateness"]

PROTOCOLS = ("sts", "dxl2")
#: Dynamixel X factory default return delay (e-Manual control tables: 250 = 500 us)
DXL_RETURN_DELAY_US = 500
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
                f"of {period_us} us a control period ({self.over_budget} over their budget: a period, or in realtime the "
                f"periods since the previous goal write), {self.packets_in} packets in, {self.packets_out} out")


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
    """Device side of the bus over a :class:`World`, speaking ``protocol`` ("sts" or "dxl2") at ``baud``.

    The wire-side injected conditions come from ``world.conditions`` (missing and duplicate ids,
    status packet corruption, seeded). ``line_baud``: the controller's line speed as the server
    reads it from the pty (None: unknown, taken to match); a controller at another speed than
    ``baud`` gets no answer and its bytes count as garbage, as servos at another baud would see them.
    In "dxl2" the servos start as a Dynamixel X ships: model 1200 (unless the world or the
    conditions name another), torque off, return delay 500 us, the model's nominal supply voltage.
    """

    def __init__(self, world: World, *, lockstep: bool, baud: int = 1_000_000, protocol: str = "sts") -> None:
        if protocol not in PROTOCOLS:
            raise ValueError(f"protocol must be one of {', '.join(PROTOCOLS)}, got {protocol!r}")
        self.world = world
        self.lockstep = lockstep
        self.baud = baud
        self.protocol = protocol
        self.line_baud: int | None = None
        self.byte_us = BYTE_BITS * 1e6 / baud
        self.stats = BusStats()
        self.garbage_bytes = 0  # bytes received at the wrong line speed
        self._tick_busy = 0.0
        self._feed_now: float | None = None  # the monotonic time of the bytes being fed (realtime)
        self._last_goal_at: float | None = None  # realtime: when the previous goal SYNC WRITE came
        self._booted = False
        c = world.conditions
        self._dead: list[tuple[int, int]] = [(sid, 0) for sid in sorted(c.missing)]  # (device id, from world time us)
        self._duplicate = c.duplicate
        self._corrupt = c.corrupt
        self._rng = random.Random(c.seed)
        self._out: deque[tuple[float, bytes]] = deque()  # realtime: (release time, bytes)
        self._free_at = 0.0
        self.t0 = time.monotonic()
        self.steps_wall = 0
        self.lateness = PlantLateness()
        self.devices: dict[int, Device] | dict[int, DxlDevice]
        self.handler: StsHandler | DxlHandler
        if protocol == "sts":
            sts: dict[int, Device] = {st.id: ServoDevice(st) for st in world.servos}
            sts.update({world.imu.id: world.imu, world.probe.id: world.probe})
            self.devices = sts
            self.handler = StsHandler(sts, self._alive, world.refresh_if_stale, self._goal_written)
        else:
            for st in world.servos:
                if world.model_number is None:
                    st.model = c.models.get(st.id, MODEL_XL330)
                st.torque = False  # as shipped
                st.return_delay_us = DXL_RETURN_DELAY_US
                if not st.fault & Fault.VOLTAGE:
                    st.voltage_dv = dxl_model(st.model).nominal_voltage_dv
            dxl: dict[int, DxlDevice] = {st.id: DxlServo(st, baud=baud) for st in world.servos}
            dxl.update({world.imu.id: DxlRegisterFile(world.imu), world.probe.id: DxlRegisterFile(world.probe)})
            self.devices = dxl
            self.handler = DxlHandler(dxl, self._alive, world.refresh_if_stale, self._goal_written)

    def kill(self, dev_id: int, at_us: int) -> None:
        """Device ``dev_id`` stops answering from world time ``at_us`` (``--dead-servo ID@SECONDS``)."""
        self._dead.append((dev_id, at_us))

    def _alive(self, dev: Device | DxlDevice) -> bool:
        for dev_id, at in self._dead:
            if dev_id == dev.id and self.world.time_us >= at:
                return False
        return getattr(dev, "alive", True)

    def _goal_written(self) -> None:
        """A SYNC WRITE covered the goal position: one control period (lockstep: of physics too)."""
        if self.lockstep:
            self.world.step()
        self._close_tick()

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
        # the cycle's budget: one control period, or in realtime the whole periods since the previous goal
        # write (a board that writes goals every k-th tick, its bus period, has k periods for a cycle)
        budget = self.world.period_us
        if not self.lockstep and self._feed_now is not None:
            if self._last_goal_at is not None:
                budget *= max(1, round((self._feed_now - self._last_goal_at) * 1e6 / self.world.period_us))
            self._last_goal_at = self._feed_now
        if self._tick_busy > budget:
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
    def _on_wire(self, dev_id: int, reply: bytes) -> bytes:
        """A status packet as the controller receives it: broken checksum (``corrupt``), collided
        with the twin's answer (``duplicate``)."""
        if self._corrupt and self._rng.random() < self._corrupt:
            reply = reply[:-1] + bytes([reply[-1] ^ self._rng.randrange(1, 256)])
        if dev_id in self._duplicate:
            reply = collide(reply, reply)
        return reply

    def feed(self, data: bytes, now: float | None = None) -> bytes:
        """Bytes from the controller -> bytes to send back now (lockstep); realtime queues them by time."""
        if self.line_baud is not None and self.line_baud != self.baud:
            self.garbage_bytes += len(data)  # framing errors at the servos: nothing is understood
            return b""
        out = bytearray()
        self._feed_now = now
        for ins in self.handler.parser.feed(data):
            self.stats.packets_in += 1
            self._tick_busy += self._wire(len(ins.raw))
            for dev_id, reply in self.handler.handle(ins):  # type: ignore[arg-type]
                reply = self._on_wire(dev_id, reply)
                self.stats.packets_out += 1
                dev = self.devices.get(dev_id)
                delay = dev.return_delay_us if dev is not None else 0
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
