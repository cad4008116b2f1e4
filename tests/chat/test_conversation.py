"""The conversation loop on a lockstep board with scripted replies: history, observations, interruption."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import anyio
import pytest

from host.chat.conversation import Conversation
from host.chat.script import Block, ScriptError, parse_blocks
from host.ghost import make_ghost
from host.ghost.base import Ghost
from host.run.robot_session import RobotSession, SessionOptions


def test_batch_files_split_on_separator_lines_with_options() -> None:
    blocks = parse_blocks("--- interrupt-after 0.5\nfirst\n\n---\nsecond --- not a separator\n---\n\n---\nthird\n")
    assert blocks == [Block("first", 0.5, 2), Block("second --- not a separator", None, 5), Block("third", None, 9)]
    with pytest.raises(ScriptError, match="line 1: unknown separator option"):
        parse_blocks("--- interrupt-at 2\nx")
    with pytest.raises(ScriptError, match="must be >= 0"):
        parse_blocks("--- interrupt-after -1\nx")


def _scripted(session: RobotSession, replies: list[str]) -> Any:
    def ghost() -> Ghost | None:
        if not replies:
            return None
        return make_ghost("scripted", program=replies.pop(0), tokens_per_s=50, sleep=session.pacer())
    return ghost


def test_observation_markup_is_never_executed(tmp_path: Path) -> None:
    async def main() -> Conversation:
        async with RobotSession(SessionOptions(out=tmp_path, lockstep=True)) as s:
            conv = Conversation(s, _scripted(s, ['<no_such_fn/><wave times="1"/>', "Okay."]), settle_s=0.1)
            await conv.turn("wave")
            await conv.turn("again")
            return conv

    conv = anyio.run(main, backend="asyncio")
    obs = conv.messages[3]["content"]
    assert conv.messages[2] == {"role": "assistant", "content": '<no_such_fn/><wave times="1"/>'}
    assert "unknown function <no_such_fn>" in obs and "done wave(times=1)" in obs
    # the second turn ran only its own reply: nothing from the observation text was dispatched
    step = conv.turns[1].steps[0]
    assert step.executed == "Okay." and "calls:\n- done speak(text='Okay.')" in step.observation
    assert "no_such_fn" not in step.observation


def test_a_new_message_interrupts_the_running_turn(tmp_path: Path) -> None:
    reply = '<move_strides direction="forward" times="6"/><wait><wave/></wait>Never said.'

    async def main() -> Conversation:
        async with RobotSession(SessionOptions(out=tmp_path, lockstep=True)) as s:
            conv = Conversation(s, _scripted(s, [reply, "Stopped."]), settle_s=0.1)
            async with anyio.create_task_group() as tg:
                tg.start_soon(conv.turn, "walk")
                await s.runtime.streamer.wait_board_time(int((s.runtime.board_now_s() + 1.0) * 1e6))
                assert conv.acting
                conv.interrupt()  # what the interactive prompt does when a new line arrives
            await conv.turn("stop")
            return conv

    conv = anyio.run(main, backend="asyncio")
    first = conv.turns[0]
    assert first.interrupted and first.steps[0].outcome == "interrupted"
    executed = conv.messages[2]["content"]
    assert executed.startswith("<move_strides") and "Never said" not in executed
    assert "interrupted: the user interrupted" in conv.messages[3]["content"]
    assert conv.messages[3]["content"].endswith("stop")  # observations merged with the next user turn
    assert not conv.turns[1].interrupted
