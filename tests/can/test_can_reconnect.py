"""Losing the CAN link: over SLCAN the adapter is the board process, so its death takes the bus away.

The loss is reported once (LinkDown, one warning) while the reconnect attempts keep failing; a board
that comes back on another pty is found again through a callable spec; a run whose board dies ends
with one clear message, not a hang or a traceback.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from host.link import BoardClient, LinkDown
from host.link.board_process import BoardProcess, start_board
from host.motion.moves import move_to
from protocol.linkspec import LinkSpec, parse_link_spec
from protocol.messages import ServoFrame
from robots.coco import load_poses

pytestmark = pytest.mark.timeout(120)
POSES = load_poses()


@pytest.mark.realtime
def test_lost_slcan_board_is_reported_once_and_a_new_one_is_found(tmp_path: Path, caplog) -> None:
    boards: list[BoardProcess] = [start_board(["--realtime"], tmp_path / "board0.stderr", link="can:slcan:pty")]
    current: dict[str, LinkSpec] = {"spec": boards[0].spec}

    async def main() -> None:
        c = await BoardClient.connect(lambda: current["spec"], reconnect_max_s=0.1)
        try:
            await c.next_telemetry(2)
            first_name = c.port_name
            boards[0].proc.send_signal(signal.SIGKILL)  # the adapter (and the bus) vanish under the client
            # ... and stay gone (the kernel may soon hand the dead pty's name to another program's pty)
            current["spec"] = parse_link_spec(f"can:slcan:{tmp_path / 'gone'}")
            reason = await c.wait_disconnected(5)
            assert "CAN receive failed" in reason or "CAN send failed" in reason, reason
            with pytest.raises(LinkDown):
                c.send_frame(ServoFrame(0, 0xFFF, POSES["stand"]))
            with pytest.raises(LinkDown):  # a request while down fails at once, it does not wait
                await c.sync_once()
            # the reconnect attempts against the vanished pty fail (quietly); the loss was said once
            with pytest.raises(Exception):
                await c.wait_connected(0.5)
            assert c.last_disconnect_reason == reason  # the loss's cause is kept ...
            assert "cannot open CAN bus" in c.last_reconnect_error  # ... beside why reconnecting fails
            with pytest.raises(LinkDown, match="CAN receive failed.*reconnecting fails: cannot open CAN bus"):
                await c.sync_once()
            assert sum("lost" in r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING) == 1
            # the board comes back on another pty: the callable spec finds it
            boards.append(start_board(["--realtime"], tmp_path / "board1.stderr", link="can:slcan:pty"))
            current["spec"] = boards[1].spec
            await c.wait_connected(10)
            assert c.stats.reconnects == 1 and c.connected  # (the kernel may hand out the same pty name)
            assert c.port_name == f"{boards[1].spec} (node 1)" and first_name
            t = await c.next_telemetry(2)
            assert t.board_time_us < 60_000_000
            res = await move_to(c, POSES["sit"], duration_s=0.3)
            assert res.max_error_deg < 3.0
        finally:
            await c.close()

    with caplog.at_level(logging.WARNING, logger="host.link"):
        try:
            asyncio.run(main())
        finally:
            for b in boards:
                b.stop()


def test_a_spec_that_now_names_another_node_is_refused(tmp_path: Path) -> None:
    board = start_board(["--lockstep"], tmp_path / "board.stderr", link="can:slcan:pty")

    async def main() -> None:
        node = {"n": 1}

        def resolve() -> str:
            return f"can:slcan:{board.spec.channel}?node={node['n']}"

        c = await BoardClient.connect(resolve, reconnect=False)
        try:
            assert c.connected
            node["n"] = 2
            c.transport.disconnect()  # type: ignore[union-attr]
            with pytest.raises(LinkDown, match="not a CAN link to node 1"):
                await c.supervisor.connect_once()  # noqa: SLF001  (the reconnect step itself)
        finally:
            await c.close()

    try:
        asyncio.run(main())
    finally:
        board.stop()


def _children(pid: int) -> list[int]:
    """Child processes of ``pid``, whichever of its threads started them (the run starts its board
    from a worker thread, and /proc lists a child under the thread that forked it)."""
    found: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            found += [int(x) for x in (task / "children").read_text().split()]
        except OSError:
            pass
    return found


@pytest.mark.realtime
@pytest.mark.slow
def test_run_whose_slcan_board_dies_ends_with_one_clear_message(tmp_path: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-m", "host.cli", "run", "--task", "26", "--link", "can:slcan:pty",
                             "--out", str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # wait (polling the file system, bounded) until the board has logged its first frames: the run is on
        log = tmp_path / "board_frames.log"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not (log.exists() and log.stat().st_size > 2000):
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.05)  # polling interval, not synchronisation: the condition above is the event
        board = [p for p in _children(proc.pid)
                 if "firmware_sim" in Path(f"/proc/{p}/cmdline").read_bytes().decode(errors="replace")]
        assert len(board) == 1
        os.kill(board[0], signal.SIGKILL)
        out, err = proc.communicate(timeout=30)  # no hang: the run ends well before the 10 s silence limit
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 1, out[-1500:] + err[-1500:]
    lines = [ln for ln in err.splitlines() if ln.startswith("ghostshell run:")]
    assert len(lines) == 1 and "CAN" in lines[0] and "Traceback" not in err, err[-2000:]
    assert sum("lost" in ln for ln in err.splitlines()) <= 2, err[-2000:]  # the warning and the final message
    summary = json.loads((tmp_path / "summary.json").read_text())  # the partial run is still reported
    assert summary["outcome"] == "link_lost" and f"ghostshell run: {summary['extra']['link_error']}" == lines[0]
