"""The scene's movable objects as the simulation has them: a JSON Lines file next to the frame log.

SIM_STATE reports the base pose and how many objects the scene holds and have toppled, not where
each one is (the wire stays small). For what is made after a run from the board's recordings (the
video, checks), ``python -m firmware_sim --objects-log FILE`` also writes, with every SIM_STATE the
board sends, one line of simulation ground truth::

    {"t_us": 120000, "objects": {"NAME": [x, y, z, qw, qx, qy, qz], ...}}

(board time in microseconds; positions in metres, orientation as a unit quaternion, rounded to
1e-6). It is written by the board process, never sent on the link; a scene without movable objects
writes nothing. Not a frame log (:mod:`protocol.framelog` records wire frames), so a separate file.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import IO

from firmware_sim.board import Board
from protocol.messages import Message, SimState

__all__ = ["ObjectsLog"]


class ObjectsLog:
    """Writes the board's object poses at each SIM_STATE it sends (see the module docstring)."""

    def __init__(self, path: str | Path, board: Board) -> None:
        self.board = board
        self._file: IO[str] | None = open(path, "w", encoding="utf-8") if board.scene_objects else None
        self.lines = 0

    def record(self, sent: Sequence[Message]) -> None:
        """Call with what a tick returned: one line per SIM_STATE among it."""
        if self._file is None:
            return
        for m in sent:
            if isinstance(m, SimState):
                q = self.board.data.qpos
                poses = {o.name: [round(float(v), 6) for v in q[o.qpos_adr:o.qpos_adr + 7]]
                         for o in self.board.scene_objects}
                self._file.write(json.dumps({"t_us": int(m.board_time_us), "objects": poses}) + "\n")
                self.lines += 1

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
