"""The board's side of a real servo bus: joint angles to register steps, limits, faults and torque.

:class:`BusDriver` sits between the board core (:mod:`firmware_sim.board`, which thinks in joint
angles) and a :class:`~firmware_sim.servobus.base.MotorBus` (register steps). It owns the safety
rules of driving real servos:

* **Start-up** (:meth:`BusDriver.start`): open the port, ping every servo of the robot and check its
  model number against ``hardware.toml`` (a missing servo, a second or garbled answer, a wrong model:
  :class:`~firmware_sim.servobus.base.BusSetupError` naming the servo, torque never switched on),
  read the present positions and hand them to the board, which starts its command there. Torque goes
  on only after that (:meth:`BusDriver.torque_on`), so the servos' first goal is where they are.
* **Every goal inside its servo's limits**: each tick's command (rad, already clamped by the board's
  servo model to the joint range and speed) is converted with the robot's calibration
  (:func:`robots.hardware.rad_to_steps`) and clamped again, independently, to
  :func:`robots.hardware.step_limits` right before the SYNC WRITE. A servo whose torque is off is sent
  its measured position (clamped too), so torque coming back on never jumps.
* **Faults**: a servo that gives no valid answer ``miss_limit`` reads in a row (not answering, or
  garbled answers: checksum errors) is lost: left out of the reads, reported once. A servo's own
  error bits (overload, overheating, voltage) are reported at once; an overloaded or overheated
  servo's torque goes off. Each report is a :class:`BusFault` in :attr:`BusDriver.faults` (the board
  turns it into SERVO_FAULT and a NACK) and one stderr line ``board: servo 3 (elbow_flex): overload
  ...``.
* **Exit** (:meth:`BusDriver.close`): torque off on the whole bus, on every path; never raises.

Units: joint angles rad, speeds rad/s, efforts N*m (load fraction times the servo's full-scale torque,
:func:`firmware_sim.servo_load.load_full_scale`), board time us.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import IO

from firmware_sim.servobus.base import (
    CORRUPT,
    TIMEOUT,
    TORQUE_OFF_FAULTS,
    BusSetupError,
    MotorBus,
    Present,
)
from robots.description import Robot
from robots.hardware import STEP_MAX, Calibration, Hardware, rad_to_steps, step_limits, steps_to_rad

__all__ = ["BUS_MARGIN", "BusDriver", "BusFault", "ESTOP_TORQUE", "Measured", "START_TOLERANCE_STEPS", "START_TRIES"]

#: what ESTOP does to the servos: hold (torque on, hold position) or limp (torque off)
ESTOP_TORQUE = ("hold", "limp")
#: start-up asks a servo this often (ping, first read) before it counts as missing or garbled
START_TRIES = 5
#: a servo found this many steps (about 1 degree) outside its limits at start-up refuses the start
START_TOLERANCE_STEPS = 12
#: one bus cycle takes at most 1/BUS_MARGIN of the bus period (about 20 % spare: the servos' and the
#: adapter's own delays, the board's work between packets)
BUS_MARGIN = 1.2


@dataclass(frozen=True)
class Measured:
    """What the servos reported, servo order: positions (rad), speeds (rad/s), efforts (N*m). A servo
    without a valid answer keeps its last values."""

    positions: list[float]
    speeds: list[float]
    efforts: list[float]


@dataclass(frozen=True)
class BusFault:
    """One servo's fault as reported: servo index (wire order), id, name and what (e.g. ``overload``)."""

    index: int
    servo_id: int
    name: str
    what: str
    torque_off: bool = False

    @property
    def detail(self) -> str:
        """The NACK detail (at most 64 bytes), as the C firmware words it: ``servo id 3 (elbow) what``."""
        return f"servo id {self.servo_id} ({self.name}) {self.what}"[:64]


class BusDriver:
    """A robot's servos on ``bus`` (see the module doc). ``hardware``/``calibration``: the robot package's
    ``hardware.toml``/``calibration.toml``. Raises :class:`robots.datatypes.RobotDataError` when a
    calibration leaves a servo no valid range (:func:`robots.hardware.step_limits`)."""

    def __init__(self, bus: MotorBus, robot: Robot, hardware: Hardware, calibration: Calibration, *,
                 estop_torque: str = "hold", miss_limit: int = 3, err: IO[str] | None = None) -> None:
        if estop_torque not in ESTOP_TORQUE:
            raise ValueError(f"estop torque must be hold or limp, got {estop_torque!r}")
        from firmware_sim.servo_load import load_full_scale

        self.bus = bus
        self.robot = robot
        self.hardware = hardware
        self.servos = list(robot.servos)
        self.n = len(self.servos)
        self.step = float(robot.servos.model.resolution)
        self.cals = [calibration.of(s) for s in self.servos]
        #: per servo the raw goal range (steps) no write leaves
        self.limits: list[tuple[int, int]] = [step_limits(s, c, self.step) for s, c in zip(self.servos, self.cals)]
        self._sign = [c.direction * s.direction for s, c in zip(self.servos, self.cals)]
        self._full = load_full_scale(robot)
        self.estop_torque = estop_torque
        self.miss_limit = max(1, miss_limit)
        self.err: IO[str] = sys.stderr if err is None else err
        self.torque: list[bool] = [False] * self.n
        self.lost: list[bool] = [False] * self.n
        self.miss: list[int] = [0] * self.n
        self._reported: list[set[str]] = [set() for _ in range(self.n)]
        self.raw: list[int] = [0] * self.n
        self._speed: list[float] = [0.0] * self.n
        self._effort: list[float] = [0.0] * self.n
        #: the goals (steps, by servo id) of the last SYNC WRITE
        self.last_goals: dict[int, int] = {}
        #: faults found since the board last took them (:meth:`take_faults`)
        self.faults: list[BusFault] = []
        self.opened = False
        self.clamped = False
        #: the board exchanges with the bus every ``every``-th control tick (:meth:`plan`)
        self.every = 1
        self.period_s = 0.002
        #: faults reported since start (the exit summary)
        self.fault_count = 0
        self._estop_said = False

    # -- start-up ----------------------------------------------------------------------------------
    def start(self) -> list[float]:
        """Open, ping and check every servo, set the bus up, read the present positions (rad, servo
        order). Torque stays off. Raises :class:`~firmware_sim.servobus.base.BusOpenError` or
        :class:`~firmware_sim.servobus.base.BusSetupError` (one line naming the servo)."""
        self.bus.open()
        self.opened = True
        answered = False
        for k, s in enumerate(self.servos):
            ans = self.bus.ping(s.id)
            for _ in range(START_TRIES - 1):  # a noisy line may garble one answer; a missing servo stays silent
                if ans.fault is None or "twice" in ans.fault:
                    break
                ans = self.bus.ping(s.id)
            if ans.fault is not None:
                if not answered and ans.fault.startswith("does not answer") and not any(
                        self.bus.ping(o.id).fault is None for o in self.servos[k + 1:]):
                    raise BusSetupError(
                        f"no servo answers a ping ({self.n} servos, ids "
                        f"{', '.join(str(o.id) for o in self.servos)}) in {self.bus.protocol} at {self.bus.baud} "
                        "baud: check the protocol (--bus-protocol or the robot's hardware.toml), the baud and the "
                        "servos' power; torque left off")
                raise BusSetupError(f"servo {s.id} ({s.name}) {ans.fault}; torque left off")
            answered = True
            want = self.hardware.model_of(s)
            if ans.model != want:
                raise BusSetupError(f"servo {s.id} ({s.name}) reports model number {ans.model}, the robot's "
                                    f"hardware.toml says {want}; torque left off")
        self.bus.zero_return_delay([s.id for s in self.servos])  # the status packets follow at once
        self.bus.prepare([s.id for s in self.servos])
        present = self.bus.read([s.id for s in self.servos])
        for _ in range(START_TRIES - 1):
            bad = [i for i, p in present.items() if p.position is None]
            if not bad:
                break
            present.update(self.bus.read(bad))
        for i, s in enumerate(self.servos):
            p = present[s.id]
            if p.position is None or not 0 <= p.position <= STEP_MAX:
                why = "does not answer" if p.comm == TIMEOUT else "answers garbled"
                raise BusSetupError(f"servo {s.id} ({s.name}) {why} when its position is read; torque left off")
            lo, hi = self.limits[i]
            if not lo - START_TOLERANCE_STEPS <= p.position <= hi + START_TOLERANCE_STEPS:
                deg = math.degrees
                a, b = sorted((deg(self._rad(i, lo)), deg(self._rad(i, hi))))  # the effective range
                raise BusSetupError(
                    f"servo {s.id} ({s.name}) is at {deg(self._rad(i, p.position)):.1f} deg, outside its range "
                    f"{a:.0f}..{b:.0f} deg (steps {p.position}, limits {lo}..{hi}); torque left "
                    "off: move it into its range by hand and start again")
            self._take(i, p)
        return self.measured().positions

    def plan(self, period_s: float, *, lockstep: bool = False) -> str:
        """Choose the bus period for a board ticking every ``period_s`` s: the smallest whole number of
        control periods that holds one bus cycle (:meth:`cycle_seconds`) with :data:`BUS_MARGIN`, so
        a realtime board's ticks never wait for the line. Sets :attr:`every` (the board exchanges with
        the bus on every ``every``-th tick) and returns the one line for the user. A lockstep board
        exchanges every tick (``every`` 1): its time is virtual, and the plant it drives steps once per
        goal write (the C firmware words it alike)."""
        need = self.cycle_seconds()
        k = max(1, math.ceil(need * BUS_MARGIN / period_s - 1e-9))
        self.period_s = period_s
        head = f"servo bus: {self.n} servos need {need * 1000:.1f} ms a cycle at {self.bus.baud} baud: "
        if lockstep:
            self.every = 1
            return head + "goals every tick (lockstep: the plant steps on each goal write)"
        self.every = k
        return head + (f"goals every {k} ticks" if k > 1 else "goals every tick") + f" ({1 / (k * period_s):.3g} Hz)"

    def cycle_seconds(self) -> float:
        """One bus cycle (s): the sync read both ways and the sync write at the bus's baud, 10 bits a byte,
        plus each status packet's return delay (as start-up left it)."""
        return self.bus.tick_seconds(self.n)

    def summary(self) -> dict[str, object]:
        """What the exit line ``board: servo bus {json}`` records (the host copies it into summary.json)."""
        c = self.bus.counts
        return {"port": self.bus.port, "protocol": self.bus.protocol, "baud": self.bus.baud, "servos": self.n,
                "bus_period_ticks": self.every, "bus_period_ms": round(self.every * self.period_s * 1000, 3),
                "cycle_ms": round(self.cycle_seconds() * 1000, 3), "return_delay_us": self.bus.return_delay_us,
                "goal_writes": c["sync_writes"], "reads": c["sync_reads"], "timeouts": c["timeouts"],
                "checksum_errors": c["corrupt"], "faults": self.fault_count}

    # -- torque ------------------------------------------------------------------------------------
    def torque_on(self, indices: Iterable[int] | None = None) -> None:
        """Torque on (servo indices; all by default). The goal registers already hold the measured
        positions of servos whose torque was off (every tick writes them)."""
        idx = list(range(self.n)) if indices is None else list(indices)
        self.bus.set_torque([self.servos[i].id for i in idx], True)
        for i in idx:
            self.torque[i] = True

    def torque_off(self, indices: Iterable[int] | None = None) -> None:
        idx = list(range(self.n)) if indices is None else list(indices)
        self.bus.set_torque([self.servos[i].id for i in idx], False)
        for i in idx:
            self.torque[i] = False

    def on_estop(self) -> None:
        """ESTOP arrived: ``limp`` switches every servo's torque off now; ``hold`` keeps it (the board holds).
        The first ESTOP until ESTOP_CLEAR prints one stderr line saying which (the ACK does not tell)."""
        if self.estop_torque == "limp":
            self.torque_off()
        if not self._estop_said:
            self._estop_said = True
            print("board: ESTOP: " + ("every servo's torque is off (--estop-torque limp): the robot goes limp"
                                      if self.estop_torque == "limp" else
                                      "every servo holds its position, torque on (--estop-torque hold)")
                  + "; motion refused until ESTOP_CLEAR", file=self.err, flush=True)

    def on_clear(self) -> list[float]:
        """ESTOP_CLEAR: lost servos are read again (one still silent is lost anew), reported faults may be
        reported again, torque back on for every servo. Returns the measured positions (rad) the board
        resumes from."""
        self.lost = [False] * self.n
        self.miss = [0] * self.n
        self._reported = [set() for _ in range(self.n)]
        self._estop_said = False
        self.torque_on()
        return self.measured().positions

    # -- per tick ----------------------------------------------------------------------------------
    def goal_steps(self, i: int, q: float) -> int:
        """Servo ``i``'s goal register value for command ``q`` (rad), inside :attr:`limits`. A servo
        whose torque is off (or a non-finite ``q``) gets its measured position."""
        raw = rad_to_steps(self.servos[i], self.cals[i], q, self.step) if self.torque[i] and math.isfinite(q) \
            else self.raw[i]
        lo, hi = self.limits[i]
        return lo if raw < lo else hi if raw > hi else raw

    def exchange(self, cmd: Sequence[float], t_us: int) -> Measured:
        """One control tick at board time ``t_us``: ONE SYNC WRITE of the goals for ``cmd`` (rad, servo
        order), then ONE SYNC READ of every servo not lost. Returns what was measured."""
        goals = {s.id: self.goal_steps(i, cmd[i]) for i, s in enumerate(self.servos)}
        #: a command the step limits clamped this tick (a torque-on servo's goal is not its command's steps)
        self.clamped = any(self.torque[i] and math.isfinite(cmd[i]) and goals[s.id] != rad_to_steps(
            s, self.cals[i], cmd[i], self.step) for i, s in enumerate(self.servos))
        self.last_goals = goals
        self.bus.write_goals(goals)
        ids = [s.id for i, s in enumerate(self.servos) if not self.lost[i]]
        present = self.bus.read(ids)
        for i, s in enumerate(self.servos):
            p = present.get(s.id)
            if p is None:
                continue
            if p.position is None or not 0 <= p.position <= STEP_MAX:
                self.miss[i] += 1
                if self.miss[i] >= self.miss_limit:
                    self.lost[i] = True
                    self._fault(i, p.comm if p.comm in (TIMEOUT, CORRUPT) else CORRUPT, t_us)
                continue
            self.miss[i] = 0
            self._take(i, p)
            for e in p.errors:
                if e not in self._reported[i]:
                    self._reported[i].add(e)
                    self._fault(i, e, t_us)
        return self.measured()

    def _rad(self, i: int, raw: int) -> float:
        return steps_to_rad(self.servos[i], self.cals[i], raw, self.step)

    def _take(self, i: int, p: Present) -> None:
        assert p.position is not None
        self.raw[i] = p.position
        self._speed[i] = self._sign[i] * p.speed * self.step
        self._effort[i] = self._sign[i] * p.load * self._full[i]

    def measured(self) -> Measured:
        """The last measured values (see :class:`Measured`)."""
        return Measured([self._rad(i, r) for i, r in enumerate(self.raw)], self._speed[:], self._effort[:])

    def _fault(self, i: int, what: str, t_us: int) -> None:
        s = self.servos[i]
        off = what in TORQUE_OFF_FAULTS and self.torque[i]
        if off:
            self.torque_off([i])
        f = BusFault(i, s.id, s.name, what, off)
        self.fault_count += 1
        self.faults.append(f)
        del self.faults[:-64]  # bounded: the board takes them every tick
        print(f"board: servo {s.id} ({s.name}): {what} at board time {t_us / 1e6:.3f} s"
              + ("; its torque is off" if off else "") + "; every servo holds, motion refused until ESTOP_CLEAR",
              file=self.err, flush=True)

    def take_faults(self) -> list[BusFault]:
        """The faults found since the last call (oldest first)."""
        out, self.faults = self.faults, []
        return out

    # -- exit --------------------------------------------------------------------------------------
    def close(self) -> None:
        """Torque off on the whole bus (twice: a SYNC WRITE has no answer to confirm it) and close the
        port. Never raises; safe to call more than once."""
        if not self.opened:
            return
        ids = [s.id for s in self.servos]
        for _ in range(2):
            try:
                self.bus.set_torque(ids, False)
            except Exception:  # noqa: BLE001 - exit must go on: the port may be gone
                pass
        self.torque = [False] * self.n
        self.opened = False
        try:
            self.bus.close()
        except Exception:  # noqa: BLE001
            pass
