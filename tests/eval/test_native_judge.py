"""The ablation judge on hand-made board timelines, the tool schemas, and the native program."""

from __future__ import annotations

import pytest

from host.commands.prompt import build_registry
from host.tools.eval.native import (Interval, ToolCall, expected_pattern, judge, json_schema, native_program,
                              parse_arguments, tool_schemas)
from host.tools.eval.paper import ablation_tasks


def iv(function: str, start: float, end: float, **args: object) -> Interval:
    return Interval(function, dict(args), start, end)


SAY1 = iv("speak", 0.0, 1.0, text="Hello!")
MOVE = iv("run_distance", 1.1, 3.0, distance=10)
SAY2 = iv("speak", 3.05, 4.0, text="Goodbye!")


@pytest.mark.parametrize("pattern,calls,ok", [
    ("say", [SAY1], True),
    ("say", [MOVE], False),
    ("move || say", [iv("run_distance", 0.0, 2.0, distance=10), iv("speak", 0.2, 1.0, text="hi")], True),
    ("move || say", [SAY1, MOVE], False),  # speech, then the move: no overlap
    ("say -> move -> say", [SAY1, MOVE, SAY2], True),
    ("say -> move -> say", [iv("speak", 0.0, 2.0, text="Hello! Goodbye!"), iv("run_distance", 2.1, 3.0)], False),
    ("say -> move -> say", [SAY1, iv("run_distance", 0.5, 3.0), SAY2], False),  # move overlaps the first speech
    ("move -> headShake", [MOVE, iv("head_act", 3.05, 5.0, action="shake")], True),
    ("move -> headShake", [MOVE, iv("head_act", 3.05, 5.0, action="nod")], False),
    ("move || headShake || earShake", [iv("run_distance", 0, 3), iv("head_act", 0.1, 2, action="shake"),
                                       iv("shake_ear", 0.2, 2.5)], True),
    ("move || headShake || earShake", [iv("run_distance", 0, 3), iv("head_act", 0.1, 2, action="shake"),
                                       iv("shake_ear", 3.1, 4)], False),
    ("move -> (rotate || headShake)", [MOVE, iv("rotate", 3.1, 5, angle=90), iv("head_act", 3.1, 4.5, action="shake")], True),
    ("move -> (rotate || headShake)", [MOVE, iv("rotate", 3.1, 5, angle=90), iv("head_act", 5.1, 6, action="shake")], False),
    ("(smile || ears) -> (backward || say)", [iv("face_emo", 0, 2, emo="smile"), iv("shake_ear", 0, 2),
                                              iv("run_distance", 2.1, 4, distance=-10), iv("speak", 2.1, 3, text="x")], True),
    ("(smile || ears) -> (backward || say)", [iv("face_emo", 0, 2, emo="smile"), iv("shake_ear", 0, 2),
                                              iv("run_distance", 2.1, 4, distance=10), iv("speak", 2.1, 3, text="x")], False),
    ("headAct(nod, 3s)", [iv("head_act", 0, 3.02, action="nod", duration=3)], True),
    ("headAct(nod, 3s)", [iv("head_act", 0, 0.8, action="nod", duration=0.8)], False),
    ("pushUp(3)", [iv("push_up", 0, 4, times=3)], True),
    ("pushUp(3)", [iv("push_up", 0, 4, times=2)], False),
    # lifecycle-scoped termination: rotate spans the ear shaking and stops right after it
    ("rotate{earShake}", [iv("rotate", 0, 3.2), iv("shake_ear", 0.1, 3.0)], True),
    ("rotate{earShake}", [iv("rotate", 0, 2.0), iv("shake_ear", 2.1, 4.0)], False),  # native: one after the other
    ("rotate{earShake}", [iv("rotate", 0, 9.0), iv("shake_ear", 0.1, 3.0)], False),  # never stopped when done
    ("rotate{headShake, earShake}", [iv("rotate", 0, 3.3), iv("head_act", 0.1, 2, action="shake"),
                                     iv("shake_ear", 0.1, 3.0)], True),
    ("rotate{say}", [iv("rotate", 0, 3.2), iv("speak", 0.1, 1), iv("speak", 1.0, 2), iv("speak", 2, 3)], True),
])
def test_judge_patterns(pattern: str, calls: list[Interval], ok: bool) -> None:
    v = judge(pattern, calls)
    assert v.passed is ok, v.reason


def test_every_ablation_task_has_a_parseable_pattern() -> None:
    for t in ablation_tasks().values():
        judge(expected_pattern(t.id, t.expected), [])  # raises ValueError on a pattern the judge cannot read
    assert expected_pattern(13, "nested lifecycle") == "rotate{earShake}"


def test_bad_pattern_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="unknown pattern atom 'dance'"):
        judge("dance", [])


def test_tool_schemas_from_type_hints_and_ranges() -> None:
    reg, _ = build_registry(None, "paper")
    tools = {t["function"]["name"]: t["function"] for t in tool_schemas(reg, "openai")}
    assert "speak" not in tools and "face_emo" in tools and "spider_rotate" not in tools  # hidden vocabulary
    rd = tools["run_distance"]["parameters"]["properties"]["distance"]
    assert rd == {"type": "number", "minimum": -300.0, "maximum": 300.0, "default": 20.0}
    assert tools["head_act"]["parameters"]["properties"]["action"]["enum"] == ["nod", "shake"]
    anth = tool_schemas(reg, "anthropic")
    assert {t["name"] for t in anth} == set(tools) and all("input_schema" in t for t in anth)
    with pytest.raises(ValueError):
        tool_schemas(reg, "gopher")


def test_json_schema_of_plain_types() -> None:
    assert json_schema(int) == {"type": "integer"} and json_schema(bool) == {"type": "boolean"}


def test_native_program_speaks_first_then_calls_in_order() -> None:
    calls = [ToolCall("run_distance", {"distance": 10}), ToolCall("head_act", {"action": "shake"})]
    seq = native_program("Hello & bye", calls, "sequential")
    assert seq == 'Hello &amp; bye<wait><run_distance distance="10"/></wait><wait><head_act action="shake"/></wait>'
    par = native_program("Hello & bye", calls)
    assert par == 'Hello &amp; bye<wait><run_distance distance="10"/><head_act action="shake"/></wait>'
    assert native_program("", []) == ""
    with pytest.raises(ValueError):
        native_program("", calls, "whenever")
    assert parse_arguments('{"a": 1}') == {"a": 1} and parse_arguments(None) == {}
    with pytest.raises(ValueError):
        parse_arguments("[1]")
