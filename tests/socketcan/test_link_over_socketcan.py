"""The CoCo link over real SocketCAN (``can:socketcan:vcan0``): board subprocesses, the host's
BoardClient, a paper task end to end, candump captures decoded through ``robots/coco/coco.dbc``,
``cansend`` ESTOP, CAN FD, and two boards on one bus.

Everything runs in lockstep (the board advances only when the host says so), so nothing waits on
wall-clock time: every wait is a telemetry condition with a timeout.
"""

from __future__ import annotations

import asyncio
import subprocess
import sys
from collections import Counter
from collections.abc import Iterator
from functools import cached_property
from pathlib import Path
from typing import Any

import can
import cantools
import numpy as np
import pytest

from host.link import BoardClient
from host.link.board_process import BoardProcess, start_board
from host.motion.moves import move_to
from protocol.can import CanDecoder, CanFrame, CanItem
from protocol.can.ids import FunctionCode, bulk_ids, split_id
from protocol.messages import ConfigKey, FaultFlags, Flush, NackReason, ServoFrame, Telemetry
from robots.coco import load_poses
from robots.coco.motions import channel_servos
from support.candump import CandumpCapture

from e2e.conftest import TASKS, E2ERun, mask_of, run_e2e
from e2e.test_interrupt import INTERRUPT_AT, check_interrupted
from e2e.test_interrupt import PROGRAM as INTERRUPT_PROGRAM
from e2e.task_checks import check_common

pytestmark = pytest.mark.timeout(240)
CHANNEL = "vcan0"
POSES = load_poses()
ROOT = Path(__file__).resolve().parents[2]
DBC = ROOT / "robots" / "coco" / "coco.dbc"
#: the board's control tick at the default 500 Hz (us)
TICK_US = 2_000


@pytest.fixture
def boards(tmp_path: Path) -> Iterator[Any]:
    """``start(link, *args) -> BoardProcess``: board subprocesses, stopped after the test."""
    started: list[BoardProcess] = []

    def start(link: str, *args: str) -> BoardProcess:
        b = start_board(list(args), tmp_path / f"board{len(started)}.stderr", link=link)
        started.append(b)
        return b

    yield start
    for b in started:
        b.stop()


def _check_capture(path: Path, nodes: tuple[int, ...] = (1,)) -> Counter[str]:
    """Every frame of a candump log is a message of ``robots/coco/coco.dbc`` that cantools decodes
    (ISO-TP frames too: opaque PCI + bytes, with a valid PCI type); returns counts by message
    name. Fails on any unknown frame."""
    db = cantools.database.load_file(str(DBC))
    known = {m.frame_id for m in db.messages}
    bulk = {i for n in nodes for i in bulk_ids(n)}
    counts: Counter[str] = Counter()
    unknown: list[str] = []
    for msg in can.CanutilsLogReader(path):
        aid, data = msg.arbitration_id, bytes(msg.data)
        if msg.is_extended_id or msg.is_remote_frame or aid not in known:
            unknown.append(f"{aid:03X}#{data.hex()}")
            continue
        db.decode_message(aid, data)  # raises on a frame the DBC cannot decode
        counts[db.get_message_by_frame_id(aid).name] += 1
        if aid in bulk:
            assert data and data[0] >> 4 in (0, 1, 2, 3), f"ISO-TP frame with a bad PCI: {aid:03X}#{data.hex()}"
    assert not unknown, f"{len(unknown)} frame(s) not in {DBC.name}: {unknown[:10]}"
    assert counts, f"empty capture {path}"
    return counts


def test_handshake_pose_and_capture_decodes_through_the_dbc(boards: Any, tmp_path: Path) -> None:
    log = tmp_path / "capture.log"
    with CandumpCapture(CHANNEL, log):
        board = boards(f"can:socketcan:{CHANNEL}", "--lockstep")

        async def main() -> None:
            async with await BoardClient.connect(board.spec) as c:
                assert c.caps is not None and c.caps.servo_count == 12 and c.caps.lockstep
                res = await move_to(c, POSES["sit"], duration_s=0.5)
                assert res.max_error_deg < 3.0
                assert c.stats.decode_errors == 0 and c.stats.frame_nacks == 0

        asyncio.run(main())
    counts = _check_capture(log)
    for name in ("SERVO_FRAME_N1", "TELEMETRY_N1", "ADVANCE_N1", "ACK_N1", "BULK_TO_BOARD_N1", "BULK_TO_HOST_N1"):
        assert counts[name] > 0, (name, counts)


def test_fd_link_sends_one_frame_per_servo_frame(boards: Any, tmp_path: Path) -> None:
    log = tmp_path / "capture.log"
    with CandumpCapture(CHANNEL, log) as capture:
        board = boards(f"can:socketcan:{CHANNEL}?fd=1", "--lockstep")

        async def main() -> None:
            async with await BoardClient.connect(board.spec) as c:
                res = await move_to(c, POSES["crouch"], duration_s=0.3)
                assert res.max_error_deg < 3.0

        asyncio.run(main())
    servo = [m for m in capture.messages() if m.arbitration_id == 0x081]
    assert servo and all(m.is_fd and len(m.data) > 8 for m in servo)


def test_cansend_estop_stops_the_board_within_one_tick(boards: Any) -> None:
    """can-utils' ``cansend vcan0 001#`` (ESTOP for node 1, from another process on the bus) while a
    motion is under way. A lockstep board runs while ADVANCE or accepted frames cover the time, so
    it is paused at a known tick P; the ESTOP is on the bus before the frames of the next 100 ms
    and the ADVANCE past them (one bus keeps its order), so the tick after P already holds: the
    frame due at P + 1 tick and every later one are refused (NACK ESTOPPED), none is applied."""
    board = boards(f"can:socketcan:{CHANNEL}", "--lockstep")

    async def main() -> None:
        async with await BoardClient.connect(board.spec) as c:
            now = c.board_now_estimate()
            for k in range(1, 5):  # the motion so far: frames up to now + 40 ms
                c.send_frame(ServoFrame(now + 10_000 * k, 0xFFF, POSES["crouch"]))
            await c.advance(now + 40_000)
            before = await c.wait_for(lambda t: t.board_time_us >= now + 40_000, 5)
            assert not before.faults & FaultFlags.ESTOP
            paused = before.board_time_us
            subprocess.run(["cansend", CHANNEL, "001#"], check=True)
            seqs = [c.send_frame(ServoFrame(paused + TICK_US + 10_000 * k, 0xFFF, POSES["sit"])) for k in range(10)]
            await c.advance(paused + 100_000)
            later = await c.wait_for(lambda t: t.board_time_us >= paused + 100_000, 5)
            assert later.faults & FaultFlags.ESTOP, f"ESTOP not latched: faults={later.faults!r}"
            assert before.last_applied_seq <= later.last_applied_seq < seqs[0], "a frame sent after the ESTOP was applied"
            nack = await c.wait_frame_nack(seqs[0], 5)  # the frame due at the very next tick
            assert nack is not None and nack.reason is NackReason.ESTOPPED, nack
            moved = max(abs(a - b) for a, b in zip(before.positions, later.positions))
            assert moved < 0.05, f"servos moved {moved} rad after the ESTOP"

    asyncio.run(main())


def test_two_boards_on_vcan0_only_the_addressed_node_moves_and_both_can_run(boards: Any, tmp_path: Path) -> None:
    b1 = boards(f"can:socketcan:{CHANNEL}?node=1", "--lockstep")
    b2 = boards(f"can:socketcan:{CHANNEL}?node=2", "--lockstep")
    log = tmp_path / "capture.log"

    async def main() -> None:
        async with await BoardClient.connect(b1.spec) as c1:
            target = c1.board_now_estimate() + 40_000
            await c1.advance(target)
            start1 = await c1.wait_for(lambda t: t.board_time_us >= target, 5)
            with CandumpCapture(CHANNEL, log):
                async with await BoardClient.connect(b2.spec) as c2:  # a run addressing node 2
                    res = await move_to(c2, POSES["sit"], duration_s=0.4)
                    assert res.max_error_deg < 3.0
            target = c1.board_now_estimate() + 40_000
            await c1.advance(target)
            end1 = await c1.wait_for(lambda t: t.board_time_us >= target, 5)
            moved = max(abs(a - b) for a, b in zip(start1.positions, end1.positions))
            assert moved < 0.01, f"node 1 moved by {moved} rad while node 2 was addressed"
            assert end1.last_applied_seq == start1.last_applied_seq
            async with await BoardClient.connect(b2.spec) as c2:  # and both at once
                r1, r2 = await asyncio.gather(move_to(c1, POSES["crouch"], duration_s=0.3),
                                              move_to(c2, POSES["stand"], duration_s=0.3))
                assert r1.max_error_deg < 3.0 and r2.max_error_deg < 3.0

    asyncio.run(main())
    counts = _check_capture(log, nodes=(1, 2))
    assert counts["SERVO_FRAME_N2"] > 0 and counts["SERVO_FRAME_N1"] == 0, counts


def test_paper_task_end_to_end_over_socketcan(tmp_path: Path) -> None:
    """Task 5 (a nod, then a wave), lockstep, the board started on vcan0 by the runner, captured;
    the same checks as the pty e2e tests (tests/e2e), and the capture decodes through the DBC."""
    log = tmp_path / "capture.log"
    with CandumpCapture(CHANNEL, log):
        run = run_e2e(str(TASKS[5].ground_truth), tmp_path / "run", task_label="task 5",
                      link=f"can:socketcan:{CHANNEL}", emulate_board=True)
    check_common(run)
    assert [c.function for c in run.calls] == ["wait", "head_act", "wave"], run.table()
    counts = _check_capture(log)
    assert counts["SERVO_FRAME_N1"] > 100 and counts["TELEMETRY_N1"] > 100, counts
    # and the project's own reader: ghostshell log decode (DBC + reassembly) finds nothing unknown
    proc = subprocess.run([sys.executable, "-m", "host.cli", "log", "decode", str(log)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0 and "UNKNOWN" not in proc.stdout, proc.stderr[-2000:]


def _host_to_board(path: Path, node: int = 1, receiver: str = "board") -> list[Any]:
    """The host-to-board (or, with ``receiver="host"``, board-to-host) messages of a candump log,
    reassembled by the protocol's own CAN decoder; fails on any frame it cannot decode."""
    dec = CanDecoder(node, receiver=receiver)
    out = []
    for m in can.CanutilsLogReader(path):
        frame = CanFrame(m.arbitration_id, bytes(m.data), m.is_fd, m.is_extended_id, m.is_remote_frame)
        for item in dec.feed(frame):
            assert isinstance(item, CanItem), item
            out.append(item.msg)
    return out


class CanE2ERun(E2ERun):
    """:class:`E2ERun` whose board telemetry comes from the board's CAN frame log (candump format)."""

    @cached_property
    def telemetry(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        reports = [m for m in _host_to_board(self.out / "board_frames.log", receiver="host") if isinstance(m, Telemetry)]
        assert reports, f"no TELEMETRY in {self.out / 'board_frames.log'}"
        return (np.asarray([r.board_time_us * 1e-6 for r in reports]), np.asarray([r.positions for r in reports]),
                np.asarray([r.velocities for r in reports]))


def test_interruption_over_socketcan_flushes_and_settles(tmp_path: Path) -> None:
    """tests/e2e/test_interrupt.py's lockstep run over vcan0: FLUSH of head and body seen on the bus."""
    log = tmp_path / "capture.log"
    with CandumpCapture(CHANNEL, log):
        run = CanE2ERun(run_e2e(INTERRUPT_PROGRAM, tmp_path / "run", interrupt_at=INTERRUPT_AT,
                                link=f"can:socketcan:{CHANNEL}", emulate_board=True).report)
    check_interrupted(run)
    flushes = [m for m in _host_to_board(log) if isinstance(m, Flush)]
    masks = {int(f.mask) for f in flushes}
    assert mask_of(channel_servos("body")) in masks and mask_of(channel_servos("head")) in masks, flushes
    t_int_us = (run.t0 + INTERRUPT_AT) * 1e6
    assert all(t_int_us <= f.from_us <= t_int_us + 300_000 for f in flushes), flushes


WATCHDOG = FaultFlags.WATCHDOG_HOLD | FaultFlags.WATCHDOG_FAULT


@pytest.mark.realtime
def test_watchdog_over_socketcan(boards: Any) -> None:
    """A realtime board on vcan0: the host goes silent, the watchdog holds; it speaks again, it resumes."""
    board = boards(f"can:socketcan:{CHANNEL}", "--realtime", "--watchdog-ms", "100")

    async def main() -> None:
        # a realtime board inside UML takes most of its one CPU: give the handshake time
        async with await BoardClient.connect(board.spec, handshake_timeout=20.0, reply_timeout=5.0) as c:
            # The subject is HOLD and resume, not the crouch: inside UML the host and the board share
            # one CPU with the other test worker outside, and a stall of the guest over 1.1 s (the
            # default 100 + 1 000 ms) latched WATCHDOG_FAULT in CI before the test began
            await c.configure(ConfigKey.CROUCH_AFTER_MS, 60_000)
            await c.estop_clear()  # (a crouch latched before the line above, during the connect, ends here)
            # (TICK_OVERRUN may show: a realtime board inside UML is slower than real time)
            await c.wait_for(lambda t: not t.faults & WATCHDOG, 5)
            c.keepalive = False
            await c.wait_for(lambda t: bool(t.faults & FaultFlags.WATCHDOG_HOLD), 5)
            c.keepalive = True
            await c.wait_for(lambda t: not t.faults & FaultFlags.WATCHDOG_HOLD, 5)

    asyncio.run(main())


#: cansend frames the board must count and survive: short, bad part index, bulk garbage, remote,
#: 29-bit id, an FD frame on a classic link, a servo frame part with a wrong length
GARBAGE = ["081#01", "081#1F00000000000000", "101#", "601#3000", "081#R", "00000081#0000000000000000",
           "081##1" + "00" * 12, "481#0000"]


def test_garbage_frames_from_cansend_are_counted_never_fatal(boards: Any) -> None:
    board = boards(f"can:socketcan:{CHANNEL}?fd=1", "--lockstep")

    async def main() -> None:
        async with await BoardClient.connect(board.spec) as c:
            start = c.board_now_estimate() + 20_000
            await c.advance(start)
            t0 = await c.wait_for(lambda t: t.board_time_us >= start, 5)
            for frame in GARBAGE:
                subprocess.run(["cansend", CHANNEL, frame], check=True)
            # one bus keeps the order: the garbage reaches the board before this ADVANCE
            await c.advance(t0.board_time_us + 40_000)
            t1 = await c.wait_for(lambda t: t.board_time_us >= t0.board_time_us + 40_000, 5)
            assert t1.link_errors >= t0.link_errors + 4, (t0.link_errors, t1.link_errors)
            assert t1.link_errors > t0.link_errors and not t1.faults
            res = await move_to(c, POSES["crouch"], duration_s=0.3)
            assert res.max_error_deg < 3.0 and c.connected
            assert c.stats.decode_errors == 1  # of the garbage only 481#0000 (a short TELEMETRY part) is the host's

    asyncio.run(main())
