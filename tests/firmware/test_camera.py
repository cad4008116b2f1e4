"""The head camera: PNG in CAMERA_CHUNKs, rendered in the loop (lockstep) or in a worker (realtime)."""

from __future__ import annotations

from firmware_sim.board import Board
from protocol.messages import Advance, CameraCapture, CameraChunk, Nack

from .conftest import make_board

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _png(chunks: list[CameraChunk], request_id: int) -> bytes:
    mine = sorted((c for c in chunks if c.request_id == request_id), key=lambda c: c.index)
    assert mine and [c.index for c in mine] == list(range(mine[0].total))
    return b"".join(c.data for c in mine)


def test_lockstep_capture_replies_with_png_chunks() -> None:
    board = make_board()
    replies = board.handle(CameraCapture(5, 64, 48), seq=2)
    if replies and isinstance(replies[0], Nack):  # no GL backend on this machine: a clear refusal
        assert "renderer" in replies[0].detail.lower()
        return
    assert _png([r for r in replies if isinstance(r, CameraChunk)], 5).startswith(PNG_MAGIC)


def test_worker_renders_off_the_loop_and_the_loop_sends_the_chunks() -> None:
    board: Board = make_board()
    why = board.start_camera_worker()
    try:
        if why is not None:
            (nack,) = board.handle(CameraCapture(9, 64, 48), seq=4)
            assert isinstance(nack, Nack) and nack.ack_seq == 4
            return
        assert board.handle(CameraCapture(9, 64, 48), seq=4) == []  # nothing blocks the loop
        board.handle(Advance(board.now_us + 60_000_000), seq=5)
        chunks: list[CameraChunk] = []
        ticks = 0
        while not any(c.index == c.total - 1 for c in chunks):
            chunks += [m for m in board.tick() if isinstance(m, CameraChunk)]
            ticks += 1
            assert ticks < 30_000, "the camera worker never delivered"
        assert _png(chunks, 9).startswith(PNG_MAGIC)
    finally:
        assert board.camera_worker is not None
        board.camera_worker.close()
