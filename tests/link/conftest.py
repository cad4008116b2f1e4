"""Real board subprocesses on real ptys for the link tests."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from host.link.board_process import BoardProcess, start_board


@pytest.fixture
def board_factory(tmp_path: Path) -> Iterator[Callable[..., BoardProcess]]:
    """``board_factory("--lockstep", ...)`` starts a board; all are stopped at teardown."""
    boards: list[BoardProcess] = []

    def make(*args: str) -> BoardProcess:
        b = start_board(list(args), tmp_path / f"board{len(boards)}.stderr")
        boards.append(b)
        return b

    yield make
    for b in boards:
        b.stop()
