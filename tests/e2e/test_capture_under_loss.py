"""A head-camera capture over a lossy link completes, whole and unaltered (selective repeat).

A 160x120 PNG is ~100 CAMERA_CHUNKs; over CAN each is a ~37-frame ISO-TP transfer, so at a few
per cent frame loss most chunks of the first pass are lost. The host asks for the missing ones
with CAMERA_RESEND until the image is whole (``BoardClient.capture``); the board answers from the
image it kept. The image must be byte-identical to the one a fault-free board renders from the
same (lockstep, untouched) state. Nothing waits on wall time except the host's own re-request
timer, which is what is under test.
"""

from __future__ import annotations

import io
from pathlib import Path

import anyio
import pytest
from PIL import Image

from host.link.board_process import start_board
from host.link import BoardClient

LOSSY = "drop=0.01,corrupt=0.01,dup=0.005,reorder=0.005"  # the paper mix


def _capture(link: str, out: Path, faults: str | None) -> tuple[bytes, int]:
    out.mkdir()
    args = ["--lockstep"] + (["--faults", faults, "--fault-seed", "7"] if faults else [])
    board = start_board(args, out / "board.stderr", link=link)

    async def main() -> tuple[bytes, int]:
        async with await BoardClient.connect(board.spec, handshake_timeout=8.0) as client:
            png = await client.capture(160, 120, timeout=60.0)
            return png, client.stats.retries

    try:
        return anyio.run(main, backend="asyncio")
    finally:
        board.stop()


@pytest.mark.parametrize("link", ["pty", "can:slcan:pty"])
def test_capture_over_a_lossy_link_is_whole_and_identical(link: str, tmp_path: Path) -> None:
    clean, _ = _capture(link, tmp_path / "clean", None)
    lossy, asked_again = _capture(link, tmp_path / "lossy", LOSSY)
    assert Image.open(io.BytesIO(lossy)).size == (160, 120)
    assert lossy == clean  # every chunk arrived unaltered, none twice, none missing
    assert asked_again > 0  # the loss really cost chunks, and the host asked for them again
