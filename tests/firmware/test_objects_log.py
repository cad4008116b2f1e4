"""The board's objects log: the scene's movable objects' poses with every SIM_STATE, nothing on the wire."""

from __future__ import annotations

import json
from pathlib import Path

from firmware_sim.board import Board
from firmware_sim.config import BoardConfig
from firmware_sim.objects_log import ObjectsLog
from protocol.messages import Advance, SimState


def _run(board: Board, log: ObjectsLog, until_us: int) -> list[SimState]:
    board.handle(Advance(until_us), 1)
    sims = []
    while board.can_tick():
        out = board.tick()
        log.record(out)
        sims += [m for m in out if isinstance(m, SimState)]
    log.close()
    return sims


def test_one_line_per_sim_state_with_every_movable_object(tmp_path: Path) -> None:
    board = Board(BoardConfig(lockstep=True, scene="bottles"))
    path = tmp_path / "objects.jsonl"
    sims = _run(board, ObjectsLog(path, board), 200_000)
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    assert len(lines) == len(sims) > 5
    assert [r["t_us"] for r in lines] == [s.board_time_us for s in sims]
    names = [o.name for o in board.scene_objects]
    assert names and all(list(r["objects"]) == names for r in lines)
    last = lines[-1]["objects"]
    for o in board.scene_objects:  # the pose the simulation has now: position and unit quaternion
        assert last[o.name] == [round(float(v), 6) for v in board.data.qpos[o.qpos_adr:o.qpos_adr + 7]]
        assert abs(sum(v * v for v in last[o.name][3:]) - 1.0) < 1e-5


def test_a_scene_without_objects_writes_nothing(tmp_path: Path) -> None:
    board = Board(BoardConfig(lockstep=True, scene="empty"))
    path = tmp_path / "objects.jsonl"
    _run(board, ObjectsLog(path, board), 60_000)
    assert not path.exists()


def test_an_unwritable_objects_log_is_one_line_and_exit_2(tmp_path: Path) -> None:
    import subprocess
    import sys

    bad = tmp_path / "no" / "such" / "objects.jsonl"
    p = subprocess.run([sys.executable, "-m", "firmware_sim", "--link", "pty", "--lockstep", "--scene", "bottles",
                        "--objects-log", str(bad)], capture_output=True, text=True, timeout=60)
    assert p.returncode == 2
    assert p.stderr.strip().splitlines()[-1].startswith("board: cannot write --objects-log")
