"""Helpers for board-core tests: a lockstep board driven by direct handle()/tick() calls."""

from __future__ import annotations

import pytest

from firmware_sim.board import Board
from firmware_sim.config import BoardConfig
from protocol.codec import SCHEMA_HASH
from protocol.messages import PROTOCOL_VERSION, Caps, Hello, Message


def make_board(**kw: object) -> Board:
    board = Board(BoardConfig(lockstep=True, **kw))  # type: ignore[arg-type]
    (caps,) = board.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), 0)
    assert isinstance(caps, Caps)
    return board


def run(board: Board, max_ticks: int = 100_000) -> list[Message]:
    """Tick while the host has covered the next tick; return everything the board sent."""
    out: list[Message] = []
    n = 0
    while board.can_tick():
        out += board.tick()
        n += 1
        assert n < max_ticks
    return out


@pytest.fixture
def board() -> Board:
    return make_board()
