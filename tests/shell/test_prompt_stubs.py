"""Stubs an LLM reads easily (issue 19, item 6): bounds as the paper's stubs write them, in both
formats and both CoCo vocabularies, while the mapper checks the annotations exactly as before; and
the rules' explanation of the scope attributes, whose example really runs."""

from __future__ import annotations

import re
from typing import Annotated, Literal

import pytest
from annotated_types import Interval, MaxLen

from support.coco import coco_registry
from host.shell.mapper import OutOfRange, map_element
from host.shell.prompt import RULES, bounds_text, render_prompt, render_stub, render_xml
from host.shell.types import Module, Range, params_of


class _Recorder:
    async def perform(self, behaviour, channel, args, call):  # pragma: no cover - never called here
        return None

    async def reset(self, behaviour, channel, call):  # pragma: no cover
        return None


@pytest.mark.parametrize("vocabulary", ["paper", "coco"])
@pytest.mark.parametrize("fmt", ["code", "xml"])
def test_coco_prompt_has_no_annotation_reprs(fmt: str, vocabulary: str) -> None:
    text = render_prompt(coco_registry(_Recorder(), vocabulary), format=fmt)
    assert "Interval(" not in text and "Annotated[" not in text and "MaxUtf8Bytes" not in text
    if fmt == "code":
        assert "    duration: float = 2.0,  # 0..120 s\n" in text
    else:
        assert "duration: number 0..120 s (default 2.0)" in text


def test_paper_stub_reads_like_the_papers() -> None:
    reg = coco_registry(_Recorder(), "paper")
    spec = reg.resolve("head_pose")
    assert render_stub(spec) == (
        "def head_pose(\n"
        "    yaw: float = 0.0,  # -90..90\n"
        "    pitch: float = 0.0,  # -30..30\n"
        ") -> None:\n"
        '    """Turn the head to an absolute pose in degrees; yaw < 0 looks right, yaw > 0 looks left."""')
    assert render_stub(reg.resolve("stand")).startswith('def stand(posture: Literal["normal", "forward", "backward"]'
                                                         ' = "normal") -> None:')  # no bounds: one line


def test_the_mapper_still_checks_the_declared_bounds() -> None:
    reg = coco_registry(_Recorder(), "paper")
    with pytest.raises(OutOfRange, match=r"<face_emo> duration='121' is out of range \[0, 120\]"):
        map_element(reg, "face_emo", {"duration": "121"})
    assert map_element(reg, "face_emo", {"duration": "120"}).args == {"duration": 120.0}


async def f(a: Annotated[int, Range(1, 20)] = 2, b: Annotated[float, Interval(gt=0, le=5)] | None = None,
            c: Annotated[str, MaxLen(8)] = "x", d: Annotated[float, Interval(ge=0)] = 1.0,
            e: Annotated[float, "opaque"] = 0.5, g: Literal["x", "y"] = "x") -> None:
    """Doc."""


def test_bounds_of_every_kind() -> None:
    p = {x.name: x for x in params_of(f)}
    assert bounds_text(p["a"]) == "1..20"
    assert bounds_text(p["b"]) == "> 0, <= 5"
    assert bounds_text(p["c"]) == "at most 8 characters"
    assert bounds_text(p["d"]) == ">= 0"
    assert bounds_text(p["e"]) == bounds_text(p["g"]) == ""
    spec = Module.from_functions("m", f).functions[0]
    stub = render_stub(spec)
    assert "    a: int = 2,  # 1..20\n" in stub
    assert "    b: float | None = None,  # > 0, <= 5\n" in stub
    assert "    e: Annotated[float, 'opaque'] = 0.5,\n" in stub  # metadata the prompt cannot read stays
    xml = render_xml(spec)
    assert "a: integer 1..20 (default 2)" in xml and "b: number > 0, <= 5 (optional)" in xml


class Seconds:
    """Metadata naming a unit (and bounds) the way a robot description might."""

    unit = "s"
    ge, le = 0, 9


async def h(wait: Annotated[float, Seconds()] = 1.0) -> None:
    """Doc."""


def test_a_unit_from_metadata() -> None:
    assert bounds_text(params_of(h)[0]) == "0..9 s"


def test_rules_explain_until_and_timeout_with_an_example_that_runs() -> None:
    assert 'until="any"' in RULES and 'timeout="S"' in RULES
    for mode, scope in (("async-first", "wait"), ("sync-first", "async")):
        text = render_prompt(coco_registry(_Recorder(), "paper"), mode=mode)
        assert f'<{scope} until="any" timeout="3"><f/><g/></{scope}>' in text


@pytest.mark.anyio
async def test_the_rules_example_on_the_example_functions(coco) -> None:
    """The example, with two real functions: the shorter ends the scope, the other is stopped."""
    example = re.search(r'<wait until="any" timeout="3"><f/><g/></wait>', render_prompt(
        coco_registry(_Recorder(), "paper"))).group(0)
    shell, _ = coco()
    program = example.replace("<f/>", '<head_act action="shake" duration="10"/>').replace("<g/>", "<shake_ear/>")
    tl = (await shell.run_text(program)).timeline
    assert tl.by_path("wait[0]").end == 1 and tl.one("head_act").outcome == "cancelled"
    tl = (await shell.run_text(program.replace("<shake_ear/>", '<shake_ear duration="9"/>'))).timeline
    assert tl.by_path("wait[0]").outcome == "timeout" and tl.by_path("wait[0]").end == 3
