"""The board's speed-only physics settings change no trajectory bit.

A board turns MuJoCo's island discovery off when its scene is one kinematic tree (CoCo alone); CoCo's
MJCF turns mid-phase collision filtering and sensors off. The same moving stream through a board with
those features back on must give the same qpos/qvel to the bit; with scene objects (several trees)
island discovery stays on.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from firmware_sim.board import Board
from firmware_sim.config import BoardConfig
from protocol.messages import PROTOCOL_VERSION, Hello, ServoFrame

D = mujoco.mjtDisableBit
SPEED_ONLY = int(D.mjDSBL_ISLAND) | int(D.mjDSBL_MIDPHASE) | int(D.mjDSBL_SENSOR)


def _walk(b: Board, frames: int = 150) -> bytes:
    """Every servo swinging 0.3 rad at 1.25 Hz, 50 frames/s, through ``Board.run``; the final state."""
    b.handle(Hello(PROTOCOL_VERSION, b.wire_schema.hash, 0), 0)
    lo, hi, mid = np.array(b.table.mins), np.array(b.table.maxs), np.array(b.table.neutral)
    for k in range(1, frames + 1):
        q = np.clip(mid + 0.3 * math.sin(2 * math.pi * k / 40), lo, hi)
        b.handle(ServoFrame(k * 20_000, b.table.all_mask, tuple(q.tolist())), k)
        while b.can_tick():
            b.run(256)
    return b.data.qpos.tobytes() + b.data.qvel.tobytes()


def test_speed_only_flags_keep_coco_trajectories_bit_identical() -> None:
    fast = Board(BoardConfig(lockstep=True, robot="coco"))
    assert fast.model.opt.disableflags & SPEED_ONLY == SPEED_ONLY
    slow = Board(BoardConfig(lockstep=True, robot="coco"))
    slow.model.opt.disableflags &= ~SPEED_ONLY
    assert _walk(fast) == _walk(slow)
    assert fast.sim_state().base_pos[2] > 0.05  # it stood through it


def test_island_discovery_stays_on_with_scene_objects() -> None:
    b = Board(BoardConfig(lockstep=True, robot="coco", scene="bottles"))
    assert b.model.ntree > 1 and not b.model.opt.disableflags & int(D.mjDSBL_ISLAND)
    assert b.model.opt.disableflags & int(D.mjDSBL_MIDPHASE)
