"""CAN test fixtures: boards served in-process on python-can's virtual bus, or as SLCAN subprocesses."""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from firmware_sim.board import Board
from firmware_sim.config import BoardConfig
from firmware_sim.server import BoardServer
from firmware_sim.transports import open_board_transport
from firmware_sim.transports.can import CanBoardTransport
from protocol.linkspec import LinkSpec, parse_link_spec

_channels = itertools.count()


@dataclass
class VirtualBoard:
    spec: LinkSpec  # what the host connects to
    board: Board
    server: BoardServer
    transport: CanBoardTransport
    thread: threading.Thread


@pytest.fixture
def virtual_channel() -> str:
    return f"ghostshell-test-{next(_channels)}"


@pytest.fixture
def virtual_board_factory(tmp_path: Path) -> Iterator[Callable[..., VirtualBoard]]:
    """``make(channel, node=1, lockstep=True, log=None, **cfg)``: a board thread on ``can:virtual:CHANNEL``."""
    boards: list[VirtualBoard] = []

    def make(channel: str, node: int = 1, lockstep: bool = True, log: str | None = None, fd: bool = False,
             **cfg: object) -> VirtualBoard:
        spec = parse_link_spec(f"can:virtual:{channel}?node={node}" + ("&fd=1" if fd else ""))
        transport = open_board_transport(spec, log_path=log)
        assert isinstance(transport, CanBoardTransport)
        board = Board(BoardConfig(lockstep=lockstep, **cfg))  # type: ignore[arg-type]
        server = BoardServer(board, transport)
        th = threading.Thread(target=server.serve, name=f"board-{channel}-{node}", daemon=True)
        vb = VirtualBoard(spec, board, server, transport, th)
        boards.append(vb)
        th.start()
        return vb

    yield make
    for b in boards:
        b.server.stop()
        b.thread.join(5)
        b.transport.close()
