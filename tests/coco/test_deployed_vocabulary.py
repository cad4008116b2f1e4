"""The deployed vocabulary as real outputs use it: open name sets, signed percentages, more postures, UTF-8."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import anyio
import pytest

from support.coco import coco_registry
from host.run.robot_session import RobotSession, SessionOptions
from host.shell.mapper import BadValue, map_element
from robots.coco.interface import NAME_BYTES
from robots.coco.motions import BEHAVIOURS, EAR_STATES



class Recorder:
    """Records behaviour calls instead of moving a robot."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, str, dict[str, Any]]] = []

    async def perform(self, behaviour: str, channel: str, args: dict[str, Any], call: Any) -> Any:
        self.calls.append((behaviour, channel, args))

    async def reset(self, behaviour: str, channel: str, call: Any) -> None:
        pass

    async def speak(self, text: str, call: Any) -> Any:
        self.calls.append(("speak", "speech", {"text": text}))


@pytest.mark.parametrize("element", [
    '<speech_role role="narrator" speech_rate="-20" loudness_rate="10"/>',
    '<speech_role role="海盗" emotion="excited" speech_rate="100" loudness_rate="-50"/>',
    '<speech_role role="girl" speech_rate="-20%" loudness_rate="+10%"/>',
    '<spider_arm_pull direction="forward"/>', '<spider_arm_pull direction="backward" times="1"/>',
    '<ear_state state="flattened"/>', '<ear_state state="flattened back"/>', '<ear_state state="Shy"/>',
    '<ear_state state="perked-up"/>', '<ear_state state="opponent"/>',
    '<play_bgm name="café"/>', '<play_bgm name="生日快乐"/>',
])
def test_real_output_values_map(element: str) -> None:
    reg = coco_registry(Recorder(), "coco")
    name = element[1:].split()[0]
    attrs = dict(kv.split("=", 1) for kv in element[len(name) + 2:-2].replace('" ', '"\0').split("\0"))
    map_element(reg, name, {k.strip(): v.strip('"') for k, v in attrs.items()})


@pytest.mark.parametrize(("name", "attrs", "needle"), [
    ("speech_role", {"speech_rate": "150"}, "out of range [-50, 100]"),
    ("speech_role", {"role": "x" * (NAME_BYTES + 1)}, f"at most {NAME_BYTES} allowed"),
    ("play_bgm", {"name": "生日快乐" * 3}, "36 bytes of UTF-8; at most 32"),
    ("ear_state", {"state": "flatened"}, "did you mean 'flattened'"),
    ("spider_arm_pull", {"direction": "forwards"}, "did you mean 'forward'"),
])
def test_bad_values_are_parameter_errors_with_suggestions(name: str, attrs: dict[str, str], needle: str) -> None:
    with pytest.raises(BadValue, match=needle.replace("[", r"\[").replace("(", r"\(")):
        map_element(coco_registry(Recorder(), "coco"), name, attrs)


def test_every_ear_posture_of_the_interface_has_angles() -> None:
    import typing

    from robots.coco.interface import EarState

    assert set(typing.get_args(EarState)) <= set(EAR_STATES)
    assert BEHAVIOURS["arm_pull"] is not None


def test_on_the_board_names_are_utf8_and_fallbacks_are_noted(tmp_path: Path) -> None:
    program = ('<speech_role role="narrator" speech_rate="-20" loudness_rate="10"/>'
               '<speech_role role="pirate"/>'
               '<play_bgm name="café"/><play_bgm name="生日快乐"/><play_bgm name="' + "长" * 11 + '"/>'
               '<spider_arm_pull direction="forward" times="1"/><ear_state state="flattened back" duration="0.5"/>')

    async def main() -> Any:
        async with RobotSession(SessionOptions(out=tmp_path, lockstep=True, vocabulary="coco")) as s:
            return await s.run_turn(program, settle_s=0.1)

    turn = anyio.run(main, backend="asyncio")
    tl = turn.result.timeline
    assert turn.result.error is None
    roles = tl.find("speech_role")
    assert roles[0].outcome == "done" and "'narrator'" in str(roles[0].result) and "rate -20%" in str(roles[0].result)
    assert "no voice 'pirate'" in str(roles[1].result)
    bgm = tl.find("play_bgm")
    assert [b.outcome for b in bgm] == ["done", "done", "failed"]
    assert "33 bytes of UTF-8" in str(bgm[2].error)  # refused before anything was sent
    assert tl.one("spider_arm_pull").outcome == "done" and tl.one("ear_state").outcome == "done"
    sent = [json.loads(line) for line in (tmp_path / "host_frames.jsonl").read_text(encoding="utf-8").splitlines()]
    names = {f["fields"]["name"] for f in sent if f.get("type") == "SPEAKER" and f["dir"] == "tx"}
    assert {"café", "生日快乐"} <= names, names


def test_a_robot_without_the_clip_plays_the_default_with_a_note(tmp_path: Path) -> None:
    async def main() -> Any:
        async with RobotSession(SessionOptions(out=tmp_path, lockstep=True, vocabulary="coco")) as s:
            s.runtime.clips = ("happy", "calm")
            return await s.run_turn('<play_bgm name="café"/>', settle_s=0.0)

    turn = anyio.run(main, backend="asyncio")
    assert "no clip 'café'" in str(turn.result.timeline.one("play_bgm").result)
