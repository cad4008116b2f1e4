"""``Board(reuse=...)``: a fresh board on an old board's compiled model and MjData runs exactly as a new one."""

from __future__ import annotations

import math

import pytest

from firmware_sim.board import Board
from firmware_sim.config import BoardConfig
from protocol.framing import encode_frame
from protocol.messages import Advance, Estop, ServoFrame, Telemetry
from robots.coco import load_servo_table

from .conftest import run

NEUTRAL = load_servo_table().neutral


def _drive(board: Board) -> list[bytes]:
    """0.6 s of a leg/head wiggle at 50 Hz, then 0.2 s more; TELEMETRY as wire bytes."""
    for k in range(1, 31):
        t = k * 20_000
        s = math.sin(2 * math.pi * t / 600_000)
        q = [v + (0.3 * s if i in (0, 1, 8) else 0.0) for i, v in enumerate(NEUTRAL)]
        board.handle(ServoFrame(t, 0x0FFF, tuple(q)), k)
    board.handle(Advance(800_000), 99)
    return [encode_frame(m, i) for i, m in enumerate(m for m in run(board) if isinstance(m, Telemetry))]


def test_reused_board_runs_bit_for_bit_as_a_fresh_one() -> None:
    expected = _drive(Board(BoardConfig(lockstep=True)))
    used = Board(BoardConfig(lockstep=True))
    _drive(used)
    used.handle(Estop(), 100)  # leave the old board moved, estopped, with physics state and warm-start
    run(used)
    again = Board(BoardConfig(lockstep=True), reuse=used)
    assert again.data is used.data and again.model is used.model  # nothing compiled or allocated
    assert again.now_us == 0 and not again.safety.estopped and again.data.time == 0.0
    assert _drive(again) == expected and len(expected) == 40


def test_reuse_needs_the_same_scene() -> None:
    with pytest.raises(ValueError, match="cannot reuse a 'empty' board's model for scene 'bottles'"):
        Board(BoardConfig(lockstep=True, scene="bottles"), reuse=Board(BoardConfig(lockstep=True)))
