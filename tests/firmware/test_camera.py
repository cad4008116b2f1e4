"""The head camera: PNG in CAMERA_CHUNKs, rendered in the loop (lockstep) or in a worker (realtime)."""

from __future__ import annotations

from firmware_sim.board import KEPT_IMAGES, Board
from protocol.messages import Advance, CameraCapture, CameraChunk, CameraResend, Nack, NackReason

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


def test_resend_returns_exactly_the_wanted_chunks_of_a_kept_image() -> None:
    board = make_board()
    first = board.handle(CameraCapture(5, 160, 120), seq=2)
    if first and isinstance(first[0], Nack):
        assert "renderer" in first[0].detail.lower()
        return
    chunks = [c for c in first if isinstance(c, CameraChunk)]
    assert len(chunks) > 10
    # bit k of the bitmap = chunk first + k: ask for 3, 5 and 12 (first = 3: bits 0, 2, 9)
    again = board.handle(CameraResend(5, 3, bytes([0b101, 0b10])), seq=3)
    assert [c.index for c in again if isinstance(c, CameraChunk)] == [3, 5, 12]
    assert again == [chunks[3], chunks[5], chunks[12]]  # the same image, not a new render
    assert board.handle(CameraResend(5, 0, b""), seq=4) == chunks  # empty bitmap: every chunk
    assert board.handle(CameraCapture(5, 160, 120), seq=5) == chunks  # the same request again: the same image
    # bits past the image's last chunk are ignored
    assert board.handle(CameraResend(5, len(chunks) - 1, b"\xff"), seq=6) == [chunks[-1]]


def test_only_the_last_images_are_kept() -> None:
    board = make_board()
    for rid in (1, 2, 3):
        replies = board.handle(CameraCapture(rid, 32, 24), seq=rid)
        if replies and isinstance(replies[0], Nack):
            return
    assert len(board.cameras.kept) == KEPT_IMAGES == 2
    (nack,) = board.handle(CameraResend(1, 0, b""), seq=9)
    assert isinstance(nack, Nack) and nack.reason is NackReason.BAD_VALUE and nack.ack_seq == 9
    assert "no image 1 kept" in nack.detail
    assert board.handle(CameraResend(3, 0, b"\x01"), seq=10)[0] == board.cameras.kept[3][0]
