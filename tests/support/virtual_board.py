"""A board served in this process on python-can's virtual bus (``can:virtual:CHANNEL``), in a thread.

python-can's virtual bus lives inside one process, so no board subprocess can serve it: the test
builds the :class:`firmware_sim.board.Board` and its :class:`firmware_sim.server.BoardServer` here
and the host connects to the same channel. ``serve_virtual(channel, ...)`` starts one;
:meth:`VirtualBoard.stop` stops the server thread and closes the bus (after which ``board`` may be
read: its MuJoCo state is the run's final world).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

from firmware_sim.board import Board
from firmware_sim.config import BoardConfig
from firmware_sim.server import BoardServer
from firmware_sim.transports import open_board_transport
from firmware_sim.transports.can import CanBoardTransport
from protocol.linkspec import LinkSpec, parse_link_spec

__all__ = ["VirtualBoard", "serve_virtual"]


@dataclass
class VirtualBoard:
    spec: LinkSpec  # what the host connects to
    board: Board
    server: BoardServer
    transport: CanBoardTransport
    thread: threading.Thread

    def stop(self) -> None:
        """Stop serving and close the bus (idempotent)."""
        self.server.stop()
        self.thread.join(5)
        self.transport.close()


def serve_virtual(channel: str, node: int = 1, lockstep: bool = True, log: str | None = None, fd: bool = False,
                  **cfg: object) -> VirtualBoard:
    """A board thread on ``can:virtual:CHANNEL?node=NODE``; ``cfg``: further :class:`BoardConfig` fields
    (e.g. ``robot="arm"``)."""
    spec = parse_link_spec(f"can:virtual:{channel}?node={node}" + ("&fd=1" if fd else ""))
    board = Board(BoardConfig(lockstep=lockstep, **cfg))  # type: ignore[arg-type]
    # the robot's CAN layout table, as python -m firmware_sim opens it
    transport = open_board_transport(spec, log_path=log, servo_count=board.n)
    assert isinstance(transport, CanBoardTransport)
    server = BoardServer(board, transport)
    th = threading.Thread(target=server.serve, name=f"board-{channel}-{node}", daemon=True)
    th.start()
    return VirtualBoard(spec, board, server, transport, th)
