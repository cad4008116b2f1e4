"""A NACK says the same over CAN as over serial (issue 17 item 7): over CAN the board's NACK to a servo
frame is one fixed frame with the reason code only, and the host printed `the board refused servo
frames (ESTOPPED: )`. The host now gives the reason's text (protocol.messages.nack_detail)."""

from __future__ import annotations

import asyncio

import pytest

from host.link import BoardClient
from host.link.board_process import start_board
from host.link.errors import NackError
from host.link.faultcheck import refusal_message
from protocol.messages import Nack, NackReason, ServoFrame
from robots.coco import load_poses

pytestmark = pytest.mark.timeout(60)
POSES = load_poses()


async def _refused_frame(spec: object) -> Nack:
    async with await BoardClient.connect(spec) as c:
        await c.estop()
        now = c.board_now_estimate()
        seq = c.send_frame(ServoFrame(now + 20_000, 0xFFF, POSES["crouch"]))
        nack = await c.wait_frame_nack(seq, 5)
        assert nack is not None and nack.reason is NackReason.ESTOPPED
        return nack


def test_estopped_refusal_reads_the_same_over_can_and_serial(virtual_board_factory, virtual_channel: str) -> None:
    vb = virtual_board_factory(virtual_channel)
    over_can = asyncio.run(_refused_frame(vb.spec))
    assert over_can.detail == ""  # the CAN form carries the reason code only
    board = start_board(["--lockstep"], link="pty")
    try:
        over_serial = asyncio.run(_refused_frame(board.spec))
    finally:
        board.stop()
    assert over_serial.detail  # the serial form carries the board's text
    link = "SPEC"
    said = refusal_message(over_can, link)
    assert said == refusal_message(over_serial, link)
    assert said is not None and "(ESTOPPED: estop active; send ESTOP_CLEAR)" in said
    assert str(NackError(over_can)).endswith(": ESTOPPED: estop active; send ESTOP_CLEAR")


def test_every_reason_has_a_text() -> None:
    from protocol.messages import NACK_REASON_TEXT, MsgType, nack_detail

    assert set(NACK_REASON_TEXT) == set(NackReason)
    assert nack_detail(Nack(1, MsgType.SERVO_FRAME, 99)) == "reason 99"  # type: ignore[arg-type]
