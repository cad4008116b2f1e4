"""Hostile-output limits (text, calls, queue, attribute size) and the --policy file, on virtual time."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import anyio
import pytest

from host.shell.limits import TurnLimits
from host.shell.policy import Policy, PolicyError
from host.shell.registry import Registry
from host.shell.shell import Shell
from host.shell.types import Module, Range, shell_function

pytestmark = pytest.mark.anyio

CALLS: list[tuple[str, dict]] = []


@shell_function(speech=True)
async def speak(text: str) -> None:
    """Say text."""
    CALLS.append(("speak", {"text": text}))
    await anyio.sleep(0.5)


async def nod(times: int = 1) -> None:
    """Nod."""
    CALLS.append(("nod", {"times": times}))
    await anyio.sleep(0.1)


async def run_distance(distance: Annotated[float, Range(-300, 300)] = 20.0) -> None:
    """Walk."""
    CALLS.append(("run_distance", {"distance": distance}))
    await anyio.sleep(1.0)


async def note(text: str = "") -> None:
    """Note."""
    CALLS.append(("note", {"text": text}))


def make(**kw) -> Shell:
    CALLS.clear()
    return Shell(Registry([Module.from_functions("speak", speak, channel="speech"),
                           Module.from_functions("head", nod, channel="head"),
                           Module.from_functions("body", run_distance, channel="body"),
                           Module.from_functions("misc", note, channel="misc")]), **kw)


def errors(result) -> list[str]:
    return [o.message for o in result.observations if o.kind == "error"]


async def test_text_per_turn_is_capped_with_one_error() -> None:
    shell = make(limits=TurnLimits(max_text_chars=100))
    result = await shell.run_text(["Hello there. " * 5, "More words here. " * 10, "And more. " * 10])
    spoken = "".join(c[1]["text"] for c in CALLS if c[0] == "speak")
    assert 0 < len(spoken) <= 100
    msgs = [m for m in errors(result) if "characters of text" in m]
    assert msgs == ["more than 100 characters of text in one turn; the rest is not spoken"]


async def test_calls_per_turn_refused_and_counted() -> None:
    shell = make(limits=TurnLimits(max_calls=10))
    result = await shell.run_text(["<nod/>" * 25, "<nod><nod/></nod>"])
    assert sum(1 for c in CALLS if c[0] == "nod") == 10
    errs = errors(result)
    assert any("more than 10 calls in one turn" in m for m in errs)
    assert "17 element(s) refused in all: more than 10 calls in one turn" in errs
    assert len(result.timeline) == 10  # refused elements do not grow the timeline


async def test_queued_calls_per_channel() -> None:
    shell = make(limits=TurnLimits(max_queued_per_channel=5))
    result = await shell.run_text("<nod/>" * 12)
    outcomes = [r.outcome for r in result.timeline]
    assert outcomes.count("done") == 5 and outcomes.count("failed") == 7
    assert any("channel 'head' already has 5 queued calls" in m for m in errors(result))


async def test_attribute_size() -> None:
    shell = make(limits=TurnLimits(max_attr_chars=50))
    result = await shell.run_text(f'<note text="{"x" * 51}"/><note text="ok"/>')
    assert CALLS == [("note", {"text": "ok"})]
    assert any("attribute 'text' has 51 characters; the limit is 50" in m for m in errors(result))
    assert len(result.timeline.records[0].args["text"]) <= 64  # the record keeps a bounded prefix


def test_limits_validate() -> None:
    with pytest.raises(ValueError, match="max_calls"):
        TurnLimits(max_calls=0).validate()


POLICY = """
[functions]
deny = ["note"]

[params.run_distance]
distance = { min = -50, max = 50 }

[budget.run_distance]
param = "distance"
max = 60
max_calls = 3
window_s = 60
"""


async def test_policy_refuses_before_dispatch(tmp_path: Path) -> None:
    f = tmp_path / "policy.toml"
    f.write_text(POLICY)
    policy = Policy.load(f)
    shell = make(policy=policy)
    result = await shell.run_text(
        '<note text="hi"/><run_distance distance="80"/><run_distance distance="30"/>'
        '<run_distance/><run_distance distance="20"/><nod/>'
    )
    # note denied; 80 outside bounds; 30 + 20 (default) = 50 within 60; the next 20 would make 70
    assert sorted(map(str, CALLS)) == sorted(map(str, [("run_distance", {"distance": 30.0}),
                                                       ("run_distance", {"distance": 20.0}), ("nod", {"times": 1})]))
    errs = errors(result)
    assert any("refused by policy: <note> is not allowed" in m for m in errs)
    assert any("distance=80 is outside [-50, 50]" in m for m in errs)
    assert any("would exceed the budget of 60 per 60 s (50 used)" in m for m in errs)
    assert policy.refused == 3
    # the window slides: a minute later the budget is back (same policy object, next turn)
    await anyio.sleep(61)
    await shell.run_text('<run_distance distance="40"/>')
    assert CALLS[-1] == ("run_distance", {"distance": 40.0})


async def test_policy_allow_list_and_call_budget() -> None:
    policy = Policy.from_dict({"functions": {"allow": ["run_distance"]},
                               "budget": {"run_distance": {"max_calls": 2}}})
    shell = make(policy=policy)
    result = await shell.run_text("Hi. <nod/><run_distance/><run_distance/><run_distance/>")
    assert sorted(c[0] for c in CALLS) == ["run_distance", "run_distance", "speak"]  # speech stays allowed
    assert any("budget of 2 call(s) per 60 s is used up" in m for m in errors(result))
    assert any("<nod> is not allowed" in m for m in errors(result))


@pytest.mark.parametrize(
    "text, match",
    [
        ("[functions]\nallow = 3", "functions.allow must be a list"),
        ("[params.walk]\nsteps = 3", "params.walk.steps must be a table"),
        ("[params.walk]\nsteps = { min = 5, max = 1 }", "min 5 > max 1"),
        ("[budget.walk]\nparam = 'steps'", "param and max go together"),
        ("[budget.walk]\nwindow_s = 5", "give max"),
        ("[limits]\nx = 1", "unknown table"),
        ("not toml [", "not valid TOML"),
    ],
)
def test_policy_file_errors(tmp_path: Path, text: str, match: str) -> None:
    f = tmp_path / "p.toml"
    f.write_text(text)
    with pytest.raises(PolicyError, match=match):
        Policy.load(f)
    with pytest.raises(PolicyError, match="cannot read policy"):
        Policy.load(tmp_path / "missing.toml")


@pytest.mark.parametrize(
    "text, match",
    [  # found by a fresh-user review: each of these loaded, and its limit silently never applied
        ("[functions]\ndenny = ['push_up']", r"functions: unknown key\(s\) \['denny'\]"),
        ("[functions]\ndeny = ['pushup']", "functions.deny: no function 'pushup'; did you mean push_up"),
        ("[params.run_distance]\ndistanse = { max = 5 }", "has no parameter 'distanse'; did you mean distance"),
        ("[params.no_such_fn]\nx = { max = 1 }", "params.no_such_fn: no function 'no_such_fn'"),
        ("[budget.run_distance]\nparam = 'dist'\nmax = 5", "budget.run_distance.param: <run_distance> has no parameter"),
        # ... and these raised a traceback (or failed only when a call came)
        ("[params.run_distance]\ndistance = { min = 'a', max = 5 }", "distance.min must be a number"),
        ("[budget.run_distance]\nparam = 'distance'\nmax = 'x'", "budget.run_distance.max must be a number"),
        ("[budget.run_distance]\nmax_calls = 0", "max_calls must be a whole number >= 1"),
        ("[budget.run_distance]\nmax_calls = 2\nwindow_s = 'z'", "window_s must be a number"),
    ],
)
def test_a_policy_name_that_matches_nothing_or_a_non_number_is_refused(tmp_path: Path, text: str, match: str) -> None:
    from support.coco import function_params

    f = tmp_path / "p.toml"
    f.write_text(text)
    with pytest.raises(PolicyError, match=match):
        Policy.load(f, known=function_params())
    ok = tmp_path / "ok.toml"
    ok.write_text("[functions]\ndeny = ['push_up', 'spider_push_up']\n[params.run_distance]\ndistance = { min = -50, max = 50 }\n"
                  "[budget.move_strides]\nparam = 'times'\nmax = 10\n")
    Policy.load(ok, known=function_params())
