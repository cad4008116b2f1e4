"""Two processes over a real pty: a board subprocess (firmware_sim) and the host's BoardClient.

Synchronisation is on telemetry conditions with timeouts (wait_for), never on sleeps.
"""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import serial

from host.commands.log import decode_file
from host.link import BoardClient, FaultEvent, HandshakeError, LinkDown, NackError
from host.motion.moves import max_error_deg, move_to
from protocol.codec import SCHEMA_HASH
from protocol.messages import ConfigKey, FaultFlags, NackReason, ServoFrame
from robots.coco import load_poses

pytestmark = pytest.mark.timeout(60)
POSES = load_poses()
ROOT = Path(__file__).resolve().parents[2]


def test_handshake_pose_telemetry_and_log(board_factory, tmp_path: Path) -> None:
    board = board_factory("--lockstep", "--log", str(tmp_path / "board.jsonl"))
    host_log = tmp_path / "host.jsonl"

    async def main() -> None:
        async with await BoardClient.connect(board.port, log_path=host_log) as c:
            assert c.caps is not None and c.caps.servo_count == 12 and c.caps.lockstep
            assert c.caps.schema_hash == SCHEMA_HASH
            res = await move_to(c, POSES["sit"], duration_s=0.5)
            assert res.max_error_deg < 3.0
            t = c.latest_telemetry
            assert t is not None and max_error_deg(t, POSES["sit"])[0] < 3.0
            assert t.faults & (FaultFlags.ESTOP | FaultFlags.WATCHDOG_FAULT) == 0
            assert c.stats.telemetry > 10 and c.stats.decode_errors == 0 and c.stats.frame_nacks == 0
            # telemetry keeps flowing while the board is advanced; the iterator sees it
            it = c.telemetry()
            adv = asyncio.ensure_future(c.advance(c.board_now_estimate() + 100_000))
            first = await asyncio.wait_for(anext(it), 5)
            await adv
            assert first.board_time_us > t.board_time_us
            await it.aclose()

    asyncio.run(main())
    out: list[str] = []

    class W:
        def write(self, s: str) -> None:
            out.append(s)

    assert decode_file(str(host_log), out=W(), err=W()) == 0
    text = "".join(out)
    for needle in ("tx #    0 HELLO", "rx #", "CAPS", "SERVO_FRAME", "TELEMETRY", "ADVANCE", "ACK"):
        assert needle in text, needle
    out.clear()
    assert decode_file(str(tmp_path / "board.jsonl"), out=W(), err=W()) == 0
    assert "rx #    0 HELLO" in "".join(out)


def test_reader_thread_transport_works_too(board_factory) -> None:
    """The fallback for ports without a selectable fd (e.g. Windows) runs the same session."""
    board = board_factory("--lockstep")

    async def main() -> None:
        async with await BoardClient.connect(board.port, force_thread=True) as c:
            assert c.transport is not None and c.transport._port is not None and c.transport._port.fd is None
            res = await move_to(c, POSES["stand"], duration_s=0.3)
            assert res.max_error_deg < 3.0

    asyncio.run(main())


def test_schema_mismatch_is_refused_with_a_clear_message(board_factory) -> None:
    board = board_factory("--lockstep")

    async def main() -> None:
        with pytest.raises(HandshakeError, match="(?i)schema"):
            await BoardClient.connect(board.port, schema_hash=SCHEMA_HASH ^ 0x5A5A)
        # the board is fine afterwards
        async with await BoardClient.connect(board.port) as c:
            assert c.caps is not None

    asyncio.run(main())


@pytest.mark.realtime
def test_watchdog_hold_then_latched_fault_then_clear(board_factory) -> None:
    board = board_factory("--realtime", "--watchdog-ms", "100")

    async def main() -> None:
        async with await BoardClient.connect(board.port) as c:
            est = c.clock_estimate
            assert est is not None and est.uncertainty_us < 5_000
            t = await c.next_telemetry(2)
            assert abs(c.board_now_estimate() - t.board_time_us) < 50_000  # synced clock vs. the board's report
            await c.configure(ConfigKey.CROUCH_AFTER_MS, 200)
            with pytest.raises(NackError) as ei:
                await c.configure(ConfigKey.TELEMETRY_RATE_HZ, 0)
            assert ei.value.reason is NackReason.BAD_VALUE
            events: list[FaultEvent] = []
            c.on_fault.append(events.append)
            await c.wait_for(lambda t: t.faults == 0, 2)
            c.keepalive = False  # stop feeding the watchdog
            await c.wait_for(lambda t: bool(t.faults & FaultFlags.WATCHDOG_HOLD), 3)
            await c.wait_for(lambda t: bool(t.faults & FaultFlags.WATCHDOG_FAULT), 3)
            assert any(e.raised & FaultFlags.WATCHDOG_HOLD for e in events)
            assert c.faults & FaultFlags.WATCHDOG_FAULT
            c.keepalive = True
            seq = c.send_frame(ServoFrame(c.board_now_estimate() + 50_000, 0xFFF, POSES["stand"]))
            nack = await c.wait_frame_nack(seq, 2)
            assert nack is not None and nack.reason is NackReason.FAULT_LATCHED
            await c.estop_clear()
            await c.wait_for(lambda t: not t.faults & (FaultFlags.WATCHDOG_FAULT | FaultFlags.WATCHDOG_HOLD), 3)
            res = await move_to(c, POSES["stand"], duration_s=0.3)
            assert res.max_error_deg < 3.0

    asyncio.run(main())


def test_estop_nacks_frames_until_cleared(board_factory) -> None:
    board = board_factory("--lockstep")

    async def main() -> None:
        async with await BoardClient.connect(board.port) as c:
            await c.estop()
            now = c.board_now_estimate()
            seq = c.send_frame(ServoFrame(now + 20_000, 0xFFF, POSES["crouch"]))
            nack = await c.wait_frame_nack(seq, 2)
            assert nack is not None and nack.reason is NackReason.ESTOPPED
            await c.advance(now + 60_000)
            await c.wait_for(lambda t: bool(t.faults & FaultFlags.ESTOP), 5)
            with pytest.raises(Exception, match="faulted"):
                await move_to(c, POSES["crouch"])
            await c.estop_clear()
            now = c.board_now_estimate()
            seq = c.send_frame(ServoFrame(now + 20_000, 0xFFF, POSES["neutral"]))
            await c.advance(now + 60_000)
            t = await c.wait_for(lambda t: t.last_applied_seq == seq and not t.faults & FaultFlags.ESTOP, 5)
            assert c.frame_nack(seq) is None and t.board_time_us >= now + 20_000

    asyncio.run(main())


@pytest.mark.realtime
def test_garbage_on_the_line_does_not_break_the_session(board_factory) -> None:
    board = board_factory("--realtime")
    garbage = bytes(range(1, 256)) * 3 + b"\x7e\x00\x01\x02\xff"

    async def main() -> None:
        async with await BoardClient.connect(board.port) as c:
            t0 = await c.next_telemetry(2)
            # host -> board: a second writer on the same pty line sprays garbage into the board's input
            with serial.Serial(board.port, 115200, timeout=0) as spray:
                spray.write(garbage)
                spray.flush()
            t1 = await c.wait_for(lambda t: t.link_errors > t0.link_errors, 3)
            assert t1.faults & FaultFlags.LINK_ERRORS or t1.link_errors > t0.link_errors
            # board -> host: garbage in the receive path is counted, never raised
            before = c.stats.decode_errors
            c.transport._on_data(garbage)  # type: ignore[union-attr,attr-defined]  # the serial transport's byte handler, fed as if the line had delivered this
            assert c.stats.decode_errors > before
            await c.next_telemetry(2)
            res = await move_to(c, POSES["crouch"], duration_s=0.3)
            assert res.max_error_deg < 3.0 and c.connected

    asyncio.run(main())


@pytest.mark.realtime
def test_reconnects_after_the_board_restarts(board_factory) -> None:
    first = board_factory("--realtime")
    current = {"port": first.port}

    async def main() -> None:
        c = await BoardClient.connect(lambda: current["port"], reconnect_max_s=0.2)
        try:
            await c.next_telemetry(2)
            first.proc.send_signal(signal.SIGKILL)  # the port vanishes under the client
            reason = await c.wait_disconnected(5)
            assert reason
            with pytest.raises(LinkDown):
                c.send_frame(ServoFrame(0, 0xFFF, POSES["stand"]))
            second = board_factory("--realtime")
            current["port"] = second.port
            await c.wait_connected(10)
            assert c.stats.reconnects == 1 and c.connected
            t = await c.next_telemetry(2)
            assert t.board_time_us < 60_000_000
            assert c.clock_estimate is not None
            res = await move_to(c, POSES["sit"], duration_s=0.3)
            assert res.max_error_deg < 3.0
        finally:
            await c.close()

    asyncio.run(main())


def _ghostshell(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "host.cli", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout, env=dict(os.environ, PYTHONUNBUFFERED="1"))


def test_pose_command(board_factory) -> None:
    board = board_factory("--lockstep")
    r = _ghostshell("pose", "--link", board.port, "--pose", "crouch", "--duration", "0.5")
    assert r.returncode == 0, r.stderr
    err = float(r.stdout.split("largest error ")[1].split()[0])
    assert err < 3.0
    r = _ghostshell("pose", "--link", board.port, "--pose", "dance")
    assert r.returncode == 2 and "valid poses: crouch, neutral, sit, stand" in r.stderr
    r = _ghostshell("pose", "--link", "/dev/pts/does-not-exist", "--pose", "sit")
    assert r.returncode == 2 and "there is no device '/dev/pts/does-not-exist'" in r.stderr


def test_tour_command_runs_end_to_end(tmp_path: Path) -> None:
    r = _ghostshell("tour", "--lockstep", "--duration", "0.3", "--out", str(tmp_path))
    assert r.returncode == 0, r.stderr
    assert "tour done: 6 poses" in r.stdout and "reached crouch" in r.stdout
    assert (tmp_path / "host.jsonl").stat().st_size > 0 and (tmp_path / "summary.json").exists()
    r = _ghostshell("log", "decode", str(tmp_path / "host.jsonl"), "--type", "HELLO")
    assert r.returncode == 0 and "HELLO" in r.stdout and "TELEMETRY" not in r.stdout
