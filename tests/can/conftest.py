"""CAN test fixtures: boards served in-process on python-can's virtual bus, or as SLCAN subprocesses."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from support.virtual_board import VirtualBoard, serve_virtual

__all__ = ["VirtualBoard"]

_channels = itertools.count()


@pytest.fixture
def virtual_channel() -> str:
    return f"ghostshell-test-{next(_channels)}"


@pytest.fixture
def virtual_board_factory(tmp_path: Path) -> Iterator[Callable[..., VirtualBoard]]:
    """``make(channel, node=1, lockstep=True, log=None, **cfg)``: a board thread on ``can:virtual:CHANNEL``."""
    boards: list[VirtualBoard] = []

    def make(channel: str, node: int = 1, lockstep: bool = True, log: str | None = None, fd: bool = False,
             **cfg: object) -> VirtualBoard:
        vb = serve_virtual(channel, node, lockstep, log, fd, **cfg)
        boards.append(vb)
        return vb

    yield make
    for b in boards:
        b.stop()
