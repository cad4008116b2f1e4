"""Host and board in one process on python-can's virtual bus (lockstep; no sleeps)."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from host.link import BoardClient, NackError
from host.link.moves import move_to
from protocol.messages import FaultFlags, NackReason, ServoFrame
from robots.coco import load_poses

pytestmark = pytest.mark.timeout(60)
POSES = load_poses()


def test_handshake_and_pose(virtual_board_factory, virtual_channel: str, tmp_path: Path) -> None:
    vb = virtual_board_factory(virtual_channel, log=str(tmp_path / "board_frames.log"))

    async def main() -> None:
        async with await BoardClient.connect(vb.spec, log_path=tmp_path / "host_frames.log") as c:
            assert c.caps is not None and c.caps.servo_count == 12 and c.caps.lockstep
            res = await move_to(c, POSES["sit"], duration_s=0.5)
            assert res.max_error_deg < 3.0
            assert c.stats.decode_errors == 0 and c.stats.frame_nacks == 0

    asyncio.run(main())
