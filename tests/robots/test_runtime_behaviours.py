"""RobotRuntime dispatches through its table of behaviours, each given the call it runs."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from host.runtime.robot_runtime import (
    CaptureBehaviour,
    FaceBehaviour,
    MotionBehaviour,
    MusicBehaviour,
    RobotRuntime,
    SpeechRoleBehaviour,
)
from robots.registry import load_robot

pytestmark = pytest.mark.anyio


@dataclass
class _Call:
    path: str = "capture[0]"
    element_id: int = 7
    persistent: bool = False
    handed: int = 0

    def hand_over(self) -> None:
        self.handed += 1


class _Link:
    lockstep = False

    def board_now_us(self) -> int:
        return 1_000_000

    async def capture(self, width: int, height: int) -> bytes:
        return b"png" * width

    def __getattr__(self, name: str) -> Any:  # nothing else is used by these calls
        raise AssertionError(f"unexpected link call {name}")


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


def _runtime(tmp_path: Path) -> RobotRuntime:
    robot = load_robot("coco")
    return RobotRuntime(robot, _Link(), tmp_path, initial=np.asarray(robot.pose(robot.rest_pose)))  # type: ignore[arg-type]


def test_the_table_holds_every_behaviour(tmp_path: Path) -> None:
    rt = _runtime(tmp_path)
    kinds = {name: type(b) for name, b in rt.behaviours.items()}
    assert {kinds["face_emo"], kinds["play_bgm"], kinds["capture"], kinds["speech_role"]} == {
        FaceBehaviour, MusicBehaviour, CaptureBehaviour, SpeechRoleBehaviour}
    assert all(kinds[name] is MotionBehaviour for name in rt.robot.behaviours)


async def test_perform_uses_the_call_it_is_given(tmp_path: Path) -> None:
    rt = _runtime(tmp_path)
    out = await rt.perform("capture", "camera", {}, _Call(path="a[0]/capture[1]"))
    assert out == "photo saved to capture_1.png (480 bytes)"
    assert rt.board_times == {"a[0]/capture[1]": [1.0, 1.0]}
    with pytest.raises(ValueError, match="no implementation for behaviour 'fly'"):
        await rt.perform("fly", "body", {}, _Call())
    await rt.reset("fly", "body", _Call())  # a behaviour without implementation has nothing to reset
