"""A host that speaks the wrong schema or drives another robot gets the same one-line refusal from every
board: the Python board, the native C firmware and the Cortex-M3 image on QEMU.

How each refuses: a HELLO naming another schema hash is NACKed SCHEMA_MISMATCH with the detail
``host schema 0x%08x != board 0x%08x`` (firmware_sim/board.py ``_hello``; firmware_sim/c/core/gs_board.c
``hello`` writes the same bytes), which the host words as ``the board on PORT refused the handshake: ...``
(host/link/receive.py); a HELLO carries no robot, so every board answers CAPS with its robot, servo count and
servo table hash, and the host refuses a board of another robot itself (host/link/supervisor.py,
RobotMismatch). Each board runs ``ghostshell firmware check`` twice, as a user would: a host pinned to a
foreign schema hash, then one for another robot; the lines must be the same apart from the port.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from host.link.board_process import start_board
from protocol.codec import WIRE_SCHEMA_16
from robots.registry import load_robot

pytestmark = pytest.mark.timeout(300)

FOREIGN = 0xDEADBEEF


def _expected() -> dict[str, str]:
    coco, arm = load_robot("coco"), load_robot("arm")
    return {
        "schema": (f"ghostshell firmware check: the board on PORT refused the handshake: SCHEMA_MISMATCH: host schema "
                   f"{FOREIGN:#010x} != board {WIRE_SCHEMA_16.hash:#010x}; host and board must run the same protocol "
                   "version and message schema"),
        "robot": (f"ghostshell firmware check: the board on PORT drives robot 'coco' (12 servos, servo table "
                  f"{coco.servo_table_hash:#010x}), but this host was started for 'arm' ({arm.servo_count} servos, "
                  f"servo table {arm.servo_table_hash:#010x}): start host and board with the same --robot (and the "
                  "same robot files)"),
    }


@pytest.mark.parametrize("firmware", ["python", "c", "qemu"])
def test_every_board_refuses_a_wrong_schema_or_robot_in_the_same_words(firmware: str, tmp_path: Path) -> None:
    board = start_board(["--firmware", firmware, "--lockstep"], tmp_path / "board.stderr", timeout=120)
    try:
        got: dict[str, str] = {}
        for case, extra in (("schema", ["--schema-hash", f"{FOREIGN:#x}"]), ("robot", ["--robot", "arm"])):
            r = subprocess.run([sys.executable, "-m", "host", "firmware", "check", "--link", board.port,
                                "--timeout", "20", *extra], capture_output=True, text=True, timeout=120,
                               stdin=subprocess.DEVNULL)
            assert r.returncode == 1 and r.stdout == "", (case, r.returncode, r.stdout, r.stderr)
            lines = r.stderr.strip().splitlines()
            assert len(lines) == 1, (case, r.stderr)
            got[case] = lines[0].replace(board.port, "PORT")
        assert board.proc.poll() is None  # it refused and still serves
    finally:
        board.stop()
    assert got == _expected()
