"""The board as an SLCAN adapter on a pty (a real subprocess); the host through python-can's own slcan.

Lockstep unless a test needs the wall clock; synchronisation on telemetry conditions, no sleeps.
"""

from __future__ import annotations

import asyncio
import os
import tty
from pathlib import Path

import anyio
import pytest

from host.commands.canlog_decode import decode_can_file
from host.link import BoardClient
from host.link.board_process import start_board
from host.link.canlog import iter_can_log
from host.motion.moves import move_to
from host.run.replay import replay
from host.run.runner import RunOptions, run_program
from protocol.can import CanItem
from protocol.messages import ConfigKey, FaultFlags, MsgType, NackReason, ServoFrame
from robots.coco import load_poses

pytestmark = pytest.mark.timeout(120)
POSES = load_poses()


class _Sink:
    def __init__(self) -> None:
        self.text: list[str] = []

    def write(self, s: str) -> None:
        self.text.append(s)


def test_handshake_pose_estop_and_garbage(tmp_path: Path) -> None:
    board = start_board(["--lockstep", "--log", str(tmp_path / "board_frames.log")], tmp_path / "board.stderr",
                        link="can:slcan:pty")
    try:
        assert board.spec.kind == "can" and board.spec.interface == "slcan" and board.spec.channel.startswith("/dev/")

        async def main() -> None:
            async with await BoardClient.connect(board.spec, log_path=tmp_path / "host_frames.asc") as c:
                assert c.caps is not None and c.caps.servo_count == 12 and c.caps.lockstep
                res = await move_to(c, POSES["sit"], duration_s=0.4)
                assert res.max_error_deg < 3.0
                await c.estop()
                now = c.board_now_estimate()
                seq = c.send_frame(ServoFrame(now + 20_000, 0xFFF, POSES["crouch"]))
                nack = await c.wait_frame_nack(seq, 5)
                assert nack is not None and nack.reason is NackReason.ESTOPPED
                await c.estop_clear()
                t0 = c.latest_telemetry
                assert t0 is not None
                # a second writer on the adapter's line: bad SLCAN lines and broken protocol frames
                fd = os.open(board.spec.channel, os.O_RDWR | os.O_NOCTTY)
                try:
                    tty.setraw(fd)
                    os.write(fd, b"garbage\rt0812AA\rt0811ZZ\rt0818" + b"1f00" + b"00" * 6 + b"\r\x00\xff\r")
                finally:
                    os.close(fd)
                res = await move_to(c, POSES["crouch"], duration_s=0.3)
                assert res.max_error_deg < 3.0 and c.connected
                t1 = c.latest_telemetry
                assert t1 is not None and t1.link_errors > t0.link_errors
                assert c.stats.decode_errors == 0

        asyncio.run(main())
    finally:
        board.stop()
    out, err = _Sink(), _Sink()
    assert decode_can_file(str(tmp_path / "host_frames.asc"), out, err) == 0, "".join(err.text)
    text = "".join(out.text)
    for needle in ("HELLO", "CAPS", "SERVO_FRAME", "TELEMETRY", "ESTOP", "NACK", "ESTOP_CLEAR"):
        assert needle in text, needle


@pytest.mark.realtime
def test_watchdog_over_slcan(tmp_path: Path) -> None:
    board = start_board(["--realtime", "--watchdog-ms", "100"], tmp_path / "board.stderr", link="can:slcan:pty")
    try:
        async def main() -> None:
            async with await BoardClient.connect(board.spec) as c:
                await c.configure(ConfigKey.CROUCH_AFTER_MS, 200)
                await c.wait_for(lambda t: not t.faults & (FaultFlags.WATCHDOG_HOLD | FaultFlags.WATCHDOG_FAULT), 3)
                c.keepalive = False
                await c.wait_for(lambda t: bool(t.faults & FaultFlags.WATCHDOG_FAULT), 5)
                c.keepalive = True
                await c.estop_clear()
                await c.wait_for(lambda t: not t.faults & (FaultFlags.WATCHDOG_FAULT | FaultFlags.WATCHDOG_HOLD), 5)

        asyncio.run(main())
    finally:
        board.stop()


def test_short_task_over_slcan_logs_and_replays(tmp_path: Path) -> None:
    out = tmp_path / "run"
    opts = RunOptions(program='<head_act action="nod"/><run_distance distance="10"/>', out=out, lockstep=True,
                      link="can:slcan:pty", task_label="slcan")
    report = anyio.run(run_program, opts, backend="asyncio")
    s = report.summary
    assert s.outcome == "done" and not s.fell
    assert s.base_start is not None and s.base_end is not None
    assert 0.07 < s.base_end[0] - s.base_start[0] < 0.13  # run_distance 10 cm (calibrated 10.0 cm)
    host_log = out / "host_frames.log"
    entries = list(iter_can_log(host_log))
    assert entries and all(e.dbc_name is not None for e in entries)  # no unknown frames
    kinds = {it.msg_type for e in entries for it in e.items if isinstance(it, CanItem)}
    assert {MsgType.HELLO, MsgType.CAPS, MsgType.SERVO_FRAME, MsgType.TELEMETRY, MsgType.SIM_STATE} <= kinds
    # issue 17 item 7: the host's log no longer closes before the board's last frames arrive
    from support.framelog_tail import last_frames

    assert last_frames(host_log, 60, received=True) == last_frames(out / "board_frames.log", 60, received=False)
    res = replay(out, tmp_path / "replay")
    assert res.base_end_error_mm is not None and res.base_end_error_mm < 1.0


def test_interruption_over_slcan(tmp_path: Path) -> None:
    out = tmp_path / "run"
    program = '<head_act action="nod"><move_strides direction="forward" times="6"/></head_act><wave/>'
    opts = RunOptions(program=program, out=out, lockstep=True, link="can:slcan:pty", interrupt_at=1.5)
    report = anyio.run(run_program, opts, backend="asyncio")
    assert report.result.interrupted and report.summary.outcome == "interrupted"
    flushes = [it.msg for e in iter_can_log(out / "host_frames.log") for it in e.items
               if isinstance(it, CanItem) and it.msg_type is MsgType.FLUSH]
    assert len(flushes) >= 2  # head and body channels


def test_fd_over_slcan(tmp_path: Path) -> None:
    board = start_board(["--lockstep"], tmp_path / "board.stderr", link="can:slcan:pty?fd=1")
    try:
        async def main() -> None:
            async with await BoardClient.connect(board.spec, log_path=tmp_path / "host_frames.log") as c:
                res = await move_to(c, POSES["sit"], duration_s=0.3)
                assert res.max_error_deg < 3.0 and c.stats.decode_errors == 0

        asyncio.run(main())
    finally:
        board.stop()
    servo = [e for e in iter_can_log(tmp_path / "host_frames.log") if e.dbc_name == "SERVO_FRAME_N1"]
    assert servo and all(e.frame.is_fd and len(e.frame.data) == 48 for e in servo)  # one FD frame each
