"""CoCo's interface stubs bound to behaviours: both vocabularies, renames, pinned args, clear errors."""

from __future__ import annotations

from typing import Any

import pytest

from support.coco import coco_registry
from host.shell import Shell
from host.shell.mapper import BadValue, map_element
from host.shell.prompt import render_prompt
from robots.coco import interface
from robots.coco.motions import BEHAVIOURS

pytestmark = pytest.mark.anyio


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


class Recorder:
    """Records behaviour calls instead of moving a robot (the binding's translation is under test)."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, str, dict[str, Any]]] = []

    async def perform(self, behaviour: str, channel: str, args: dict[str, Any], call: Any) -> Any:
        self.calls.append((behaviour, channel, args))

    async def reset(self, behaviour: str, channel: str, call: Any) -> None:
        self.calls.append((f"reset:{behaviour}", channel, {}))

    async def speak(self, text: str, call: Any) -> Any:
        self.calls.append(("speak", "speech", {"text": text}))


@pytest.mark.parametrize("vocabulary", ["paper", "coco"])
async def test_both_vocabularies_are_accepted_whichever_is_shown(vocabulary: str) -> None:
    rec = Recorder()
    shell = Shell(coco_registry(rec, vocabulary))
    result = await shell.run_text('<display_face face="sad"/><face_emo emo="smile" duration="1"/>'
                                  '<wink_right/><spider_rotate angle="45"/><move_forward/>Hi.')
    assert result.error is None and all(r.outcome == "done" for r in result.timeline)
    assert ("face_emo", "face", {"emo": "sad", "duration": 2.0}) in rec.calls  # renamed face -> emo
    assert ("face_emo", "face", {"emo": "wink_right", "duration": 1.0}) in rec.calls  # pinned argument
    assert ("rotate", "body", {"angle": 45.0}) in rec.calls
    assert ("move_strides", "body", {"times": 1, "direction": "forward"}) in rec.calls  # one call = one stride
    assert ("speak", "speech", {"text": "Hi."}) in rec.calls


def test_prompt_shows_only_the_chosen_vocabulary() -> None:
    paper = render_prompt(coco_registry(Recorder(), "paper"), format="xml")
    coco = render_prompt(coco_registry(Recorder(), "coco"), format="xml")
    assert "<face_emo" in paper and "<display_face" not in paper
    assert "<display_face" in coco and "<face_emo" not in coco


def test_unknown_emotion_lists_the_valid_ones() -> None:
    reg = coco_registry(Recorder(), "paper")
    with pytest.raises(BadValue) as err:
        map_element(reg, "face_emo", {"emo": "grumpy"})
    for valid in ("neutral", "smile", "very_frustrated", "wink_right", "sleepy"):
        assert valid in str(err.value)


def test_every_stub_maps_to_a_behaviour_that_accepts_its_arguments() -> None:
    peripheral = {"face_emo", "play_bgm", "capture", "speech_role"}
    for vocabulary in interface.VOCABULARIES:
        for name, (_fn, info) in interface.stubs(vocabulary).items():
            assert info.behaviour in BEHAVIOURS or info.behaviour in peripheral, (vocabulary, name)
            assert info.channel in interface.CHANNELS, (vocabulary, name)


async def test_parent_element_resets_its_behaviour() -> None:
    rec = Recorder()
    await Shell(coco_registry(rec, "paper")).run_text('<head_act action="nod"><wave/></head_act>')
    names = [c[0] for c in rec.calls]
    assert sorted(names[:2]) == ["head_act", "wave"] and names[2:] == ["reset:head_act"]
