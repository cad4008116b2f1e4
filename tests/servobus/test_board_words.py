"""Board lines name the robot's own safe pose (robot.toml ``safe_pose``) for the latched watchdog: the arm
folds to ``rest``, CoCo crouches (Mode.CROUCH stays the enum and wire name)."""

from __future__ import annotations

import io

import pytest

from firmware_sim.board import Board
from firmware_sim.config import BoardConfig
from firmware_sim.safety import Mode
from firmware_sim.server import BoardServer


@pytest.mark.parametrize(("robot", "pose"), [("arm", "rest"), ("coco", "crouch")])
def test_the_latched_watchdog_names_the_safe_pose(robot: str, pose: str) -> None:
    b = Board(BoardConfig(robot=robot, lockstep=True, kernel="python"))
    b.safety.feed(0)
    kinds = []
    for _ in range(2000):
        b.tick()
        kinds += [k for _, k, _ in b.watchdog_events]
        if b.mode is Mode.CROUCH:
            break
        b.watchdog_events.clear()
    assert b.mode is Mode.CROUCH
    assert kinds == ["hold", pose]
    # the stderr line the board prints for it
    srv = BoardServer.__new__(BoardServer)
    srv.board, srv.err = b, io.StringIO()
    srv._report_watchdog()
    line = srv.err.getvalue()
    assert line.startswith(f"board: watchdog {pose} at board time "), line
    assert robot != "arm" or "crouch" not in line
