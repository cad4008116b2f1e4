"""The shell -> function seam: the scheduler hands a call its CallContext as an argument, and
SAVE/RUN live in their own object (:class:`host.shell.skill_recorder.SkillRecorder`)."""

from __future__ import annotations

import anyio
import pytest

from host.shell.context import CallContext
from host.shell.parser import EmptyTag, EndTag, StartTag, Text
from host.shell.skill_recorder import MAX_SKILL_DEPTH, SkillRecorder
from host.shell.skills import SkillError, SkillStore
from host.shell.types import Module, params_of, shell_function

from support.shell_fakes import shell_with

pytestmark = pytest.mark.anyio


async def test_a_function_and_its_reset_get_their_call_as_an_argument() -> None:
    seen: list[tuple[str, str, bool, str]] = []

    async def reset(call: CallContext) -> None:
        seen.append(("reset", call.path, call.persistent, call.phase))

    @shell_function(reset=reset)
    async def hold(call: CallContext, speed: int = 1) -> None:
        seen.append(("run", call.path, call.persistent, call.phase))
        if call.persistent:
            await anyio.sleep_forever()

    r = await shell_with({"C1": [hold]}).run_text('<hold speed="2"><hold/></hold>')
    assert all(x.outcome == "done" for x in r.timeline), r.timeline.table()
    assert sorted(seen[:2]) == [("run", "hold[0]", True, "run"), ("run", "hold[0]/hold[0]", False, "run")]
    assert seen[2:] == [("reset", "hold[0]", True, "reset")]  # the two runs start in either order


async def test_the_call_parameter_is_no_attribute() -> None:
    @shell_function
    async def f(call: CallContext, x: int = 0) -> None:
        """Do f."""

    assert [p.name for p in params_of(f)] == ["x"]
    spec = Module.from_functions("m", f).functions[0]
    assert spec.call_param == "call" and spec.reset_call_param is None
    r = await shell_with({"m": [f]}).run_text('<f call="1"/>')
    assert r.timeline.one("f").outcome == "failed" and "no parameter 'call'" in (r.timeline.one("f").error or "")


def _recorder(tmp_path) -> tuple[SkillRecorder, list[tuple[str, str]], list[tuple[str, object]]]:
    seen: list[tuple[str, str]] = []
    executed: list[tuple[str, object]] = [('<SAVE name="s">', None)]
    return SkillRecorder(SkillStore(tmp_path / "skills.json"), lambda k, m: seen.append((k, m)), executed), seen, executed


def test_save_records_events_until_its_end_tag(tmp_path) -> None:
    rec, seen, executed = _recorder(tmp_path)
    rec.start({"name": "s", "description": "d"}, empty=False)
    for ev in (StartTag("a", {}), EmptyTag("b", {"x": "1"}), Text("hi"), EndTag("a")):
        rec.record(ev)
    assert rec.recording is not None
    rec.record(EndTag("SAVE"))
    assert rec.recording is None and rec.failures == 0
    assert rec.skills.get("s").program == '<a><b x="1"/>hi</a>'
    assert seen == [("info", "skill 's' saved")]
    assert executed[-1] == ("hi", None)


def test_an_unclosed_or_empty_save_fails_and_is_not_executed(tmp_path) -> None:
    rec, seen, executed = _recorder(tmp_path)
    rec.start({"name": "s"}, empty=True)
    assert rec.recording is None and rec.failures == 1
    rec.start({"name": "s"}, empty=False)
    rec.record(Text("x"))
    rec.end_of_stream()
    assert rec.failures == 2 and executed == [] and "s" not in rec.skills
    assert [k for k, _ in seen] == ["error", "error"]


def test_run_program_refuses_recursion_and_depth(tmp_path) -> None:
    rec, _, _ = _recorder(tmp_path)
    rec.skills.save("s", "", "<a/>")
    assert rec.program("s") == [EmptyTag("a", {})]
    with rec.expanding("s"):
        with pytest.raises(SkillError, match="recursive skill: s -> s"):
            rec.program("s")
    rec.stack[:] = [f"k{i}" for i in range(MAX_SKILL_DEPTH)]
    with pytest.raises(SkillError, match="nested deeper"):
        rec.program("s")


async def test_every_builtin_element_has_a_start() -> None:
    from host.shell.scheduler import ProgramRun
    from host.shell.types import BUILTINS

    assert set(ProgramRun(shell_with({}))._elements) == BUILTINS
