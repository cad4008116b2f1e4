"""Host and board in one process on python-can's virtual bus (lockstep; no sleeps)."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from host.link import BoardClient, NackError
from host.motion.moves import move_to
from protocol.messages import FaultFlags, NackReason, ServoFrame
from robots.coco import load_poses

pytestmark = pytest.mark.timeout(60)
POSES = load_poses()


def test_handshake_and_pose(virtual_board_factory, virtual_channel: str, tmp_path: Path) -> None:
    vb = virtual_board_factory(virtual_channel, log=str(tmp_path / "board_frames.log"))

    async def main() -> None:
        async with await BoardClient.connect(vb.spec, log_path=tmp_path / "host_frames.log") as c:
            assert c.caps is not None and c.caps.servo_count == 12 and c.caps.lockstep
            res = await move_to(c, POSES["sit"], duration_s=0.5)
            assert res.max_error_deg < 3.0
            assert c.stats.decode_errors == 0 and c.stats.frame_nacks == 0

    asyncio.run(main())


def test_fd_handshake_pose_and_logs(virtual_board_factory, virtual_channel: str, tmp_path: Path) -> None:
    import can

    vb = virtual_board_factory(virtual_channel, fd=True, log=str(tmp_path / "board_frames.asc"))

    async def main() -> None:
        async with await BoardClient.connect(vb.spec, log_path=tmp_path / "host_frames.blf") as c:
            res = await move_to(c, POSES["crouch"], duration_s=0.3)
            assert res.max_error_deg < 3.0

    asyncio.run(main())
    vb.server.stop()
    vb.thread.join(5)
    vb.transport.close()
    msgs = list(can.LogReader(str(tmp_path / "host_frames.blf")))
    assert any(m.is_fd and m.arbitration_id == 0x081 and len(m.data) == 48 for m in msgs)  # one FD servo frame
    assert any(m.arbitration_id == 0x481 for m in msgs)  # telemetry
    board_msgs = list(can.LogReader(str(tmp_path / "board_frames.asc")))
    assert any(m.arbitration_id == 0x601 for m in board_msgs)  # bulk (ISO-TP) to the board: HELLO


def test_estop_then_clear(virtual_board_factory, virtual_channel: str) -> None:
    vb = virtual_board_factory(virtual_channel)

    async def main() -> None:
        async with await BoardClient.connect(vb.spec) as c:
            await c.estop()
            now = c.board_now_estimate()
            seq = c.send_frame(ServoFrame(now + 20_000, 0xFFF, POSES["crouch"]))
            nack = await c.wait_frame_nack(seq, 2)
            assert nack is not None and nack.reason is NackReason.ESTOPPED
            assert nack.detail == ""  # a refused servo frame's NACK is one fixed frame: the reason only
            await c.advance(now + 60_000)
            await c.wait_for(lambda t: bool(t.faults & FaultFlags.ESTOP), 5)
            await c.estop_clear()
            now = c.board_now_estimate()
            seq = c.send_frame(ServoFrame(now + 20_000, 0xFFF, POSES["neutral"]))
            await c.advance(now + 60_000)
            t = await c.wait_for(lambda t: t.last_applied_seq == seq and not t.faults & FaultFlags.ESTOP, 5)
            assert t.board_time_us >= now + 20_000

    asyncio.run(main())


def test_broadcast_estop_stops_every_board(virtual_board_factory, virtual_channel: str) -> None:
    import can

    b1 = virtual_board_factory(virtual_channel, node=1)
    b2 = virtual_board_factory(virtual_channel, node=2)

    async def main() -> None:
        async with await BoardClient.connect(b1.spec) as c1, await BoardClient.connect(b2.spec) as c2:
            with can.Bus(interface="virtual", channel=virtual_channel) as spray:
                spray.send(can.Message(arbitration_id=0x000, data=b"", is_extended_id=False))  # cansend 000#
            for c in (c1, c2):
                await c.advance(c.board_now_estimate() + 20_000)
                await c.wait_for(lambda t: bool(t.faults & FaultFlags.ESTOP), 5)

    asyncio.run(main())


def test_two_boards_on_one_bus_only_the_addressed_one_moves(virtual_board_factory, virtual_channel: str) -> None:
    b1 = virtual_board_factory(virtual_channel, node=1)
    b2 = virtual_board_factory(virtual_channel, node=2)

    async def main() -> None:
        async with await BoardClient.connect(b1.spec) as c1, await BoardClient.connect(b2.spec) as c2:
            target = c1.board_now_estimate() + 40_000
            await c1.advance(target)
            start1 = await c1.wait_for(lambda t: t.board_time_us >= target, 5)
            res = await move_to(c2, POSES["sit"], duration_s=0.4)
            assert res.max_error_deg < 3.0
            target = c1.board_now_estimate() + 40_000
            await c1.advance(target)
            end1 = await c1.wait_for(lambda t: t.board_time_us >= target, 5)
            moved = max(abs(a - b) for a, b in zip(start1.positions, end1.positions))
            assert moved < 0.01, f"node 1 moved by {moved} rad while node 2 was addressed"
            assert end1.last_applied_seq == start1.last_applied_seq
            # and both at once
            r1, r2 = await asyncio.gather(move_to(c1, POSES["crouch"], duration_s=0.3), move_to(c2, POSES["stand"], duration_s=0.3))
            assert r1.max_error_deg < 3.0 and r2.max_error_deg < 3.0

    asyncio.run(main())


@pytest.mark.realtime
def test_garbage_frames_are_counted_never_fatal(virtual_board_factory, virtual_channel: str) -> None:
    import can

    vb = virtual_board_factory(virtual_channel, lockstep=False)

    async def main() -> None:
        async with await BoardClient.connect(vb.spec) as c:
            t0 = await c.next_telemetry(2)
            with can.Bus(interface="virtual", channel=virtual_channel) as spray:
                for aid, data in [(0x081, b"\x01"), (0x081, b"\x1f\x00" + bytes(6)), (0x101, b""), (0x601, b"\x30\x00"),
                                  (0x081, bytes([0x00, 0x08]) + bytes(6)), (0x081, bytes([0x00, 0x10]) + bytes(6))]:
                    spray.send(can.Message(arbitration_id=aid, data=data, is_extended_id=False))
                spray.send(can.Message(arbitration_id=0x081, is_remote_frame=True, dlc=8, is_extended_id=False))
            t1 = await c.wait_for(lambda t: t.link_errors >= t0.link_errors + 4, 3)
            assert t1.link_errors > t0.link_errors
            assert vb.transport.decoder.errors  # counted by kind
            res = await move_to(c, POSES["crouch"], duration_s=0.3)
            assert res.max_error_deg < 3.0 and c.connected

    asyncio.run(main())


@pytest.mark.realtime
def test_watchdog_fires_when_the_host_goes_silent(virtual_board_factory, virtual_channel: str) -> None:
    vb = virtual_board_factory(virtual_channel, lockstep=False, watchdog_ms=100)

    async def main() -> None:
        async with await BoardClient.connect(vb.spec) as c:
            await c.wait_for(lambda t: t.faults == 0, 2)
            c.keepalive = False
            await c.wait_for(lambda t: bool(t.faults & FaultFlags.WATCHDOG_HOLD), 3)
            c.keepalive = True
            await c.wait_for(lambda t: not t.faults & FaultFlags.WATCHDOG_HOLD, 3)

    asyncio.run(main())


def test_host_log_ends_with_the_boards_last_frames(virtual_board_factory, virtual_channel: str,
                                                   tmp_path: Path) -> None:
    """Issue 17 item 7: the host closed its frame log while a lockstep board was still answering its last
    frames (the last ~40 frames of the bus were in the board's log only). The host now closes it once
    the bus is quiet: both logs end with the same frames, each way."""
    from support.framelog_tail import last_frames

    vb = virtual_board_factory(virtual_channel, log=str(tmp_path / "board_frames.log"))

    async def main() -> None:
        async with await BoardClient.connect(vb.spec, log_path=tmp_path / "host_frames.log") as c:
            await move_to(c, POSES["sit"], duration_s=0.5)

    asyncio.run(main())
    vb.stop()
    host, board = tmp_path / "host_frames.log", tmp_path / "board_frames.log"
    assert last_frames(host, 60, received=True) == last_frames(board, 60, received=False)
    assert last_frames(host, 10, received=False) == last_frames(board, 10, received=True)
