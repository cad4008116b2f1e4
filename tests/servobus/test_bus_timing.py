"""The bus period (problem: a bus cycle longer than the control period): at attach the board works out one
bus cycle from the servo count, protocol, baud and the servos' return delay (written to 0 at start-up,
else the servo's own), and exchanges with the bus on every k-th tick only, k the smallest whole number of
control periods holding the cycle with ~20 % margin. The servo model runs every tick; the goals written
are that tick's command; the mirror holds between reads. In-process on the in-memory port."""

from __future__ import annotations

import pytest

from firmware_sim.board import Board
from firmware_sim.config import BoardConfig
from firmware_sim.servobus import make_bus
from firmware_sim.servobus.driver import BusDriver
from firmware_sim.servobus.fuzz import _Model
from firmware_sim.servobus.memport import MemPort
from firmware_sim.fuzz import Reader
from robots.hardware import DEFAULT_MODEL, Calibration, Hardware, rad_to_steps
from robots.registry import load_robot
from tests.servobus.helpers import ARM, N

IDS = [s.id for s in ARM.servos]


class _Line:
    """Honest servos on the in-memory port, every packet logged; ``refuse``: WRITEs answered with an error
    bit (a Dynamixel with torque on refuses EEPROM writes); the return delay register holds ``delay``."""

    def __init__(self, protocol: str, *, refuse: bool = False, delay: int = 250, robot: object = ARM) -> None:
        ids = [s.id for s in robot.servos]  # type: ignore[attr-defined]
        self.model = _Model(protocol, Reader(b""), ids, DEFAULT_MODEL[protocol])
        self.protocol, self.refuse, self.log = protocol, refuse, []  # type: ignore[var-annotated]
        for i in ids:
            self.model.table(i)[7 if protocol == "sts" else 9] = delay
        self.port = MemPort(self._answer)

    def _answer(self, pkt: bytes) -> bytes:
        self.log.append(bytes(pkt))
        sts = self.protocol == "sts"
        i, inst = (pkt[2], pkt[4]) if sts else (pkt[4], pkt[7])
        if self.refuse and inst == 3:  # refused: not stored, an error bit in the answer
            return self.model.status(i, 0x08, b"")
        return b"".join(self.model.answer(pkt, 0, False) or [])

    def driver(self, baud: int = 1_000_000, robot: object = ARM) -> BusDriver:
        return BusDriver(make_bus(self.protocol, "mem", baud, port_handler=self.port), robot,  # type: ignore[arg-type]
                         Hardware(self.protocol, baud, DEFAULT_MODEL[self.protocol]), Calibration())

    def writes(self) -> list[bytes]:
        """The goal SYNC WRITEs on the line."""
        goal = 42 if self.protocol == "sts" else 116
        return [p for p in self.log if (p[4] == 0x83 and p[5] == goal if self.protocol == "sts"
                                        else p[7] == 0x83 and p[8] == goal)]


def test_coco_on_sts_at_1_mbaud_writes_goals_every_second_tick() -> None:
    coco = load_robot("coco")
    line = _Line("sts", robot=coco)
    d = line.driver(robot=coco)
    d.start()
    assert line.model.table(1)[7] == 0  # return delay written to 0 at start-up
    text = d.plan(0.002)
    assert text == "servo bus: 12 servos need 2.1 ms a cycle at 1000000 baud: goals every 2 ticks (250 Hz)"
    assert d.every == 2
    assert "--rate" not in text
    # a lockstep board exchanges every tick (its plant steps once per goal write)
    assert d.plan(0.002, lockstep=True).endswith("goals every tick (lockstep: the plant steps on each goal write)")
    assert d.every == 1


@pytest.mark.parametrize(("protocol", "baud", "every"), [("sts", 1_000_000, 1), ("dxl2", 1_000_000, 2),
                                                          ("dxl2", 57_600, 21)])
def test_the_bus_period_holds_the_cycle_with_margin(protocol: str, baud: int, every: int) -> None:
    line = _Line(protocol)
    d = line.driver(baud)
    d.start()
    d.plan(0.002)
    assert d.every == every
    need = d.cycle_seconds()
    assert need * 1.2 <= every * 0.002 and (every == 1 or need * 1.2 > (every - 1) * 0.002)


def test_a_refused_return_delay_write_counts_the_servos_own() -> None:
    """A servo that refuses the write keeps its delay (250 x 2 us): the cycle counts it, read back."""
    line = _Line("dxl2", refuse=True, delay=250)
    d = line.driver()
    d.start()
    assert d.bus.return_delay_us == 500.0
    zero = _Line("dxl2").driver()
    zero.start()
    assert zero.bus.return_delay_us == 0.0
    assert d.cycle_seconds() == pytest.approx(d.bus.tick_bytes(N) * 10 / 1e6 + N * 500e-6)
    assert zero.cycle_seconds() == pytest.approx(zero.bus.tick_bytes(N) * 10 / 1e6)


def _run(every: int, ticks: int) -> tuple[_Line, Board, list[list[float]], list[float]]:
    line = _Line("dxl2")
    d = line.driver()
    board = Board(BoardConfig(robot="arm", kernel="python", lockstep=True), robot=ARM)
    q = d.start()
    d.every = every
    d.torque_on()
    board.attach_bus(d, q)
    cmds, seen = [], []
    board.anchor_v[0] = 0.8  # a target far off: the speed-limited command moves every tick
    board.anchor_t[0] = 0
    for _ in range(ticks):
        board.tick()
        cmds.append(board.servo.cmd.tolist())
        seen.append(float(board.positions()[0]))
    return line, board, cmds, seen


def test_the_board_exchanges_every_kth_tick_only() -> None:
    line, board, cmds, seen = _run(2, 10)
    writes = line.writes()
    assert len(writes) == 5  # ticks 0, 2, 4, 6, 8
    assert board.bus is not None and board.bus.bus.counts["sync_reads"] == 1 + 5  # start-up's read + 5
    # the command moved on every tick (the servo model runs every tick), the goals are that tick's command
    pan = [c[0] for c in cmds]
    assert all(b != a for a, b in zip(pan, pan[1:]))
    s0 = ARM.servos[0]
    for k, w in enumerate(writes):
        goal = int.from_bytes(w[13:17], "little")  # id 1's goal in the SYNC WRITE (after addr, len, id)
        assert goal == rad_to_steps(s0, Calibration().of(s0), cmds[2 * k][0], ARM.servos.model.resolution)
    # the mirror holds between reads: the measured angle changes only on a bus tick
    assert all(seen[k] == seen[k - 1] for k in range(1, 10, 2))
    assert all(seen[k] != seen[k - 2] for k in range(2, 10, 2))


def test_lockstep_stays_deterministic() -> None:
    a, _, _, _ = _run(2, 12)
    b, _, _, _ = _run(2, 12)
    assert a.log == b.log
