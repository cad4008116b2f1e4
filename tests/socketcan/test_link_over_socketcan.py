"""The CoCo link over real SocketCAN (``can:socketcan:vcan0``): board subprocesses, the host's
BoardClient, a paper task end to end, candump captures decoded through ``protocol/coco.dbc``,
``cansend`` ESTOP, CAN FD, and two boards on one bus.

Everything runs in lockstep (the board advances only when the host says so), so nothing waits on
wall-clock time: every wait is a telemetry condition with a timeout.
"""

from __future__ import annotations

import asyncio
import subprocess
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import anyio
import can
import cantools
import pytest

from host.link import BoardClient
from host.link.board_process import BoardProcess, start_board
from host.link.moves import move_to
from host.run.runner import RunOptions, run_program
from protocol.can.ids import FunctionCode, bulk_ids, split_id
from protocol.messages import FaultFlags, NackReason, ServoFrame
from robots.coco import load_poses
from robots.coco.tasks import load_tasks
from support.candump import CandumpCapture

pytestmark = pytest.mark.timeout(240)
CHANNEL = "vcan0"
POSES = load_poses()
ROOT = Path(__file__).resolve().parents[2]
DBC = ROOT / "protocol" / "coco.dbc"
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
    """Every frame of a candump log is a DBC message that cantools decodes, or an ISO-TP frame
    (valid PCI) on a node's bulk identifiers; returns counts by message name. Fails on anything else."""
    db = cantools.database.load_file(str(DBC))
    known = {m.frame_id for m in db.messages}
    bulk = {i for n in nodes for i in bulk_ids(n)}
    counts: Counter[str] = Counter()
    unknown: list[str] = []
    for msg in can.CanutilsLogReader(path):
        aid, data = msg.arbitration_id, bytes(msg.data)
        if msg.is_extended_id or msg.is_remote_frame:
            unknown.append(f"{aid:X} ext/rtr")
        elif aid in known:
            db.decode_message(aid, data)  # raises on a frame the DBC cannot decode
            counts[db.get_message_by_frame_id(aid).name] += 1
        elif aid in bulk and data and data[0] >> 4 in (0, 1, 2, 3):
            counts["ISO-TP " + ("to board" if split_id(aid)[0] is FunctionCode.BULK_TO_BOARD else "to host")] += 1
        else:
            unknown.append(f"{aid:03X}#{data.hex()}")
    assert not unknown, f"{len(unknown)} frame(s) neither in {DBC.name} nor ISO-TP: {unknown[:10]}"
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
    for name in ("SERVO_FRAME_N1", "TELEMETRY_N1", "ADVANCE_N1", "ACK_N1", "ISO-TP to board", "ISO-TP to host"):
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


def test_two_boards_on_vcan0_only_the_addressed_node_moves(boards: Any, tmp_path: Path) -> None:
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

    asyncio.run(main())
    counts = _check_capture(log, nodes=(1, 2))
    assert counts["SERVO_FRAME_N2"] > 0 and counts["SERVO_FRAME_N1"] == 0, counts


def test_paper_task_end_to_end_over_socketcan(tmp_path: Path) -> None:
    """Task 5 (a nod, then a wave), lockstep, the board started on vcan0 by the runner, captured."""
    task = load_tasks()[5]
    log = tmp_path / "capture.log"
    with CandumpCapture(CHANNEL, log):
        opts = RunOptions(program=str(task.ground_truth), task_label="task 5", lockstep=True,
                          link=f"can:socketcan:{CHANNEL}", emulate_board=True, out=tmp_path / "run")
        rep = anyio.run(run_program, opts, backend="asyncio")
    assert rep.result.error is None, rep.result.error
    assert rep.summary.outcome == "done" and all(c.outcome == "done" for c in rep.calls), rep.calls
    assert {c.function for c in rep.calls} >= {"head_act", "wave"}
    assert not rep.summary.fell
    link = rep.summary.extra["link"]
    assert link["late"] == 0 and link["dropped"] == 0 and link["frame_nacks"] == 0 and link["decode_errors"] == 0, link
    counts = _check_capture(log)
    assert counts["SERVO_FRAME_N1"] > 100 and counts["TELEMETRY_N1"] > 100, counts
