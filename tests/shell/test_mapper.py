"""Registry, mapper T(v) conversions and errors, prompt rendering, skills."""

from __future__ import annotations

import enum
import json
import subprocess
import sys
from typing import Annotated, Literal

import anyio
import pytest

from host.shell.mapper import (
    BadValue, MissingParameter, OutOfRange, UnknownFunctionError, UnknownParameter, map_element,
)
from host.shell.prompt import render_prompt
from host.shell.registry import Registry, RegistryError
from host.shell.shell import Shell
from host.shell.skills import SkillStore
from host.shell.types import Module, Range, shell_function
from host.speech.sentences import SentenceSplitter


class Mood(enum.Enum):
    HAPPY = "happy"
    SAD = "sad"


class HeadIface:
    """Head."""

    @shell_function(aliases=("nod_head",))
    async def head_act(self, action: Literal["nod", "shake"], speed: Annotated[float, Range(0, 10)] = 1.0,
                       times: int = 1, loud: bool = False, mood: Mood = Mood.HAPPY, note: str | None = None) -> None:
        """Move the head."""


class HeadImpl:
    def __init__(self):
        self.calls = []

    async def head_act(self, **kw) -> None:
        self.calls.append(kw)
        await anyio.sleep(1)


@pytest.fixture
def reg():
    return Registry([Module.bind("head", HeadIface, HeadImpl())])


def test_conversion_to_declared_types(reg):
    m = map_element(reg, "head_act", {"action": "shake", "speed": "2.5", "times": "3", "loud": "TRUE",
                                      "mood": "sad", "note": "hi", "sync": "true"})
    assert m.args == {"action": "shake", "speed": 2.5, "times": 3, "loud": True, "mood": Mood.SAD, "note": "hi"}
    assert m.sync and m.spec.name == "head_act"
    assert map_element(reg, "nod_head", {"action": "nod", "mood": "HAPPY", "note": "null"}).args["note"] is None
    assert map_element(reg, "head_act", {"action": "nod", "times": "2.0"}).args["times"] == 2


@pytest.mark.parametrize("name,attrs,exc,words", [
    ("head_akt", {}, UnknownFunctionError, ["head_act"]),
    ("head_act", {"action": "nod", "sped": "1"}, UnknownParameter, ["sped", "speed"]),
    ("head_act", {}, MissingParameter, ["action"]),
    ("head_act", {"action": "nod", "times": "two"}, BadValue, ["times", "integer"]),
    ("head_act", {"action": "nod", "speed": "fast"}, BadValue, ["number"]),
    ("head_act", {"action": "nod", "speed": "11"}, OutOfRange, ["[0, 10]"]),
    ("head_act", {"action": "wiggle"}, BadValue, ["'nod'", "'shake'"]),
    ("head_act", {"action": "nod", "mood": "meh"}, BadValue, ["'HAPPY'", "'SAD'"]),
    ("head_act", {"action": "nod", "loud": "maybe"}, BadValue, ["boolean"]),
    ("head_act", {"action": "nod", "speed": "nan"}, BadValue, ["finite"]),
])
def test_mapping_errors_are_clear(reg, name, attrs, exc, words):
    with pytest.raises(exc) as info:
        map_element(reg, name, attrs)
    for w in words:
        assert w in str(info.value)


def test_mount_unmount_alias_and_conflicts(reg):
    assert "nod_head" in reg and reg.resolve("nod_head") is reg.resolve("head_act")
    with pytest.raises(RegistryError):
        reg.mount(Module.bind("head", HeadIface, HeadImpl()))
    with pytest.raises(RegistryError):
        reg.mount(Module.bind("head2", HeadIface, HeadImpl()))  # same function names

    async def wait() -> None: ...

    with pytest.raises(RegistryError):
        reg.mount(Module.from_functions("bad", wait))
    reg.alias("nodding", "head_act")
    assert reg.aliases_of(reg.resolve("head_act")) == ["nod_head", "nodding"]
    v = reg.version
    reg.unmount("head")
    assert "head_act" not in reg and "nodding" not in reg and reg.version == v + 1


def test_bind_requires_async_implementation():
    class Impl:
        def head_act(self, **kw):
            pass

    with pytest.raises(TypeError):
        Module.bind("head", HeadIface, Impl())


def test_sentence_splitter_the_shell_uses():
    b = SentenceSplitter()
    assert b.feed("Pi is 3.") == [] and b.feed("14. Nice") == ["Pi is 3.14."]
    assert b.feed("!") == [] and b.feed(" 好的。再见") == ["Nice!", "好的。"]
    assert b.flush() == ["再见"] and b.flush() == []
    assert b.feed("   \n  ") == [] and b.flush() == []


def test_prompt_changes_with_mount_and_mode(reg):
    code = render_prompt(reg)
    assert ('def head_act(\n    action: Literal["nod", "shake"],\n    speed: float = 1.0,  # 0..10\n' in code)  # bounds as the paper's stubs read
    assert 'mood: Literal["HAPPY", "SAD"] = "HAPPY"' in code and '"""Move the head.' in code
    assert "Also callable as: nod_head" in code and "Async-First" in code
    xml = render_prompt(reg, format="xml", mode="sync-first")
    assert '<head_act action="nod|shake" speed="1.0"' in xml and "speed: number 0..10 (default 1.0)" in xml
    assert "Sync-First" in xml and "<async>" in xml

    @shell_function(speech=True)
    async def say(text: str) -> None:
        """Speak."""

    reg.mount(Module.from_functions("voice", say))
    with_voice = render_prompt(reg)
    assert "def say(text: str)" in with_voice and "spoken aloud with <say>" in with_voice
    reg.unmount("voice")
    assert render_prompt(reg) == code
    reg.unmount("head")
    assert "head_act" not in render_prompt(reg) and "no functions are mounted" in render_prompt(reg)


def test_prompt_cli_falls_back_to_example_interface():
    out = subprocess.run([sys.executable, "-m", "host", "prompt", "--format", "xml"], capture_output=True, text=True)
    if out.returncode != 0 and "No module named host.__main__" in out.stderr:  # pragma: no cover
        pytest.skip("host is not runnable with -m")
    assert out.returncode == 0, out.stderr
    assert "<head_act" in out.stdout and "<!--" in out.stdout
    out = subprocess.run([sys.executable, "-m", "host", "prompt", "--interface", "host.testing.quadruped:modules",
                          "--mode", "sync-first"], capture_output=True, text=True)
    assert out.returncode == 0 and "def head_act(" in out.stdout and "Sync-First" in out.stdout
    bad = subprocess.run([sys.executable, "-m", "host", "prompt", "--interface", "no.such:thing"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "cannot load interface" in bad.stderr


# -- skills -------------------------------------------------------------------

@pytest.mark.anyio
async def test_save_records_without_running_and_run_replays(coco, tmp_path):
    path = tmp_path / "skills.json"
    shell, impl = coco(skills=SkillStore(path))
    prog = ('<SAVE name="greet" description="nod &amp; smile"><wait><head_act action="nod"/></wait>'
            'Hi &lt;3<face_emo emo="smile"/></SAVE>')
    r = await shell.run_text(prog)
    assert len(r.timeline) == 0 and not impl.log
    saved = json.loads(path.read_text())
    assert saved["greet"]["description"] == "nod & smile"
    assert saved["greet"]["program"] == '<wait><head_act action="nod"/></wait>Hi &lt;3<face_emo emo="smile"/>'
    assert "- greet: nod & smile" in shell.prompt()

    shell2, _ = coco(skills=SkillStore(path))  # persisted
    r = await shell2.run_text('<shake_ear/><RUN id="greet"/><wave/>')
    tl = r.timeline
    assert tl.one("head_act").start == 1  # the skill's <wait> is a barrier after shake_ear, inline
    assert tl.one("speak", text="Hi <3").start == 2 and tl.one("face_emo").start == 2
    assert tl.one("wave").start == 2 and tl.one("RUN").outcome == "done"


@pytest.mark.anyio
async def test_run_inside_save_and_recursion(coco):
    shell, _ = coco()
    await shell.run_text('<SAVE name="a"><wave/></SAVE><SAVE name="b" description="twice"><RUN id="a"/><RUN id="a"/></SAVE>')
    r = await shell.run_text('<RUN id="b"/>')
    assert [x.start for x in r.timeline.find("wave")] == [0, 2]
    r = await shell.run_text('<SAVE name="a"><RUN id="b"/></SAVE>')  # a -> b -> a
    assert any("recursive" in o.message for o in r.observations)
    assert shell.skills.get("a").program == "<wave/>"  # unchanged
    r = await shell.run_text('<SAVE name="self"><RUN id="self"/></SAVE><RUN id="nope"/>')
    assert "self" not in shell.skills
    assert r.timeline.one("RUN").outcome == "failed" and "unknown skill" in r.timeline.one("RUN").error


@pytest.mark.anyio
async def test_runtime_recursion_guard(coco, tmp_path):
    path = tmp_path / "s.json"
    path.write_text(json.dumps({"loop": {"description": "", "program": '<wave/><RUN id="loop"/>'}}))
    shell, _ = coco(skills=SkillStore(path))  # a hand-edited file can still hold a recursive skill
    r = await shell.run_text('<RUN id="loop"/>')
    assert len(r.timeline.find("wave")) == 1
    assert any("recursive skill: loop -> loop" in o.message for o in r.observations)


def test_interface_only_modules_render_but_do_not_run():
    from host.testing.quadruped import Head

    reg = Registry([Module.interface_only("head", Head)])
    assert "def head_act(" in render_prompt(reg)

    async def go():
        return await Shell(reg).run_text("<head_act/>")

    r = anyio.run(go)
    assert r.timeline.one("head_act").outcome == "failed" and "no implementation" in r.timeline.one("head_act").error
