"""Scopes (issue 19): ``<wait>``/``<async>`` with ``until="all|any"`` and ``timeout``, bad
scope attributes, and ``<RUN>`` as an element whose children are the skill's calls.

All on Trio's virtual clock (``conftest.py``): a fake that takes ``d`` seconds ends at exactly ``d``.
"""

from __future__ import annotations

import anyio
import pytest

from host.shell.limits import TurnLimits
from host.shell.scheduler import MAX_DEPTH
from host.shell.shell import Shell
from host.shell.skills import SkillStore
from host.shell.types import shell_function

from support.shell_fakes import LOG, fake, shell_with, timed_stream

pytestmark = pytest.mark.anyio



def _shell(**kw):
    return shell_with({"head": [fake("nod", 3, reset_seconds=0.25)], "ears": [fake("flap", 0.5)],
                       "body": [fake("walk", 3), fake("wave", 2)], "face": [fake("smile", 1)]}, **kw)


def errors(r) -> list[str]:
    return [o.message for o in r.observations if o.kind == "error"]


# -- until="any" -------------------------------------------------------------------------------

async def test_any_ends_at_the_first_child_and_cancels_the_others():
    r = await _shell().run_text('<wait until="any"><nod d="3"/><flap d="0.5"/></wait><smile/>')
    tl = r.timeline
    w, nod, flap, smile = tl.by_path("wait[0]"), tl.one("nod"), tl.one("flap"), tl.one("smile")
    assert (flap.start, flap.end, flap.outcome) == (0, 0.5, "done")
    assert (nod.start, nod.end, nod.outcome) == (0, 0.5, "cancelled")
    assert (w.start, w.end, w.outcome, w.ended_by) == (0, 0.5, "done", "wait[0]/flap[0]")
    assert w.args == {"until": "any"}
    assert smile.start == 0.5  # what follows the scope starts when it ended
    assert any(o.kind == "info" and o.path == "wait[0]" and "ended when its child wait[0]/flap[0] ended"
               in o.message and "1 call(s)" in o.message for o in r.observations), r.observation_text()


async def test_all_is_the_default_and_the_papers_meaning():
    for prog in ('<wait><nod d="3"/><flap d="0.5"/></wait><smile/>',
                 '<wait until="all"><nod d="3"/><flap d="0.5"/></wait><smile/>'):
        tl = (await _shell().run_text(prog)).timeline
        assert tl.by_path("wait[0]").end == 3 and tl.one("nod").outcome == "done" and tl.one("smile").start == 3
        assert tl.by_path("wait[0]").ended_by is None


async def test_any_resets_a_cancelled_persistent_child_and_cancels_its_subtree():
    LOG.clear()
    r = await _shell().run_text('<wait until="any"><nod><walk d="3"/></nod><flap d="0.5"/></wait><smile/>')
    tl = r.timeline
    nod, walk = tl.one("nod"), tl.one("walk")
    assert walk.outcome == "cancelled" and walk.end == 0.5
    assert nod.outcome == "cancelled" and nod.end == 0.75  # its reset hook (0.25 s) ran, shielded
    assert any(e == "nod:reset" for _, e in LOG)
    w = tl.by_path("wait[0]")
    assert w.end == 0.5 and w.outcome == "done"  # the scope ended at the cut ...
    assert tl.one("smile").start == 0.75  # ... and completes once what it cancelled has stopped


async def test_any_cancels_children_that_arrive_after_it_ended():
    sh = _shell()
    r = await sh.run(timed_stream([(0, '<wait until="any"><flap d="0.5"/>'), (1, '<walk/>'), (2, "</wait><wave/>")]))
    tl = r.timeline
    assert tl.one("walk").outcome == "cancelled" and tl.one("walk").start is None
    assert tl.by_path("wait[0]").end == 0.5
    assert tl.one("wave").start == 2  # dispatched when </wait> arrived


async def test_a_cancelled_child_does_not_end_an_any_scope():
    sh = _shell()
    out = {}

    async def run():
        out["r"] = await sh.run_text('<wait until="any"><nod d="3"/><walk d="2"/></wait>')

    async with anyio.create_task_group() as tg:
        tg.start_soon(run)
        await anyio.sleep(1)
        assert sh.interrupt(["head"]) == 1
    tl = out["r"].timeline
    assert tl.one("nod").outcome == "interrupted" and tl.one("walk").outcome == "done"
    assert tl.by_path("wait[0]").ended_by == "wait[0]/walk[0]" and tl.by_path("wait[0]").end == 2


async def test_a_failed_child_ends_an_any_scope():
    async def boom() -> None:
        await anyio.sleep(0.2)
        raise RuntimeError("servo fault")

    sh = shell_with({"head": [fake("nod", 3)], "ears": [shell_function(boom, name="flap")]})
    tl = (await sh.run_text('<wait until="any"><nod/><flap/></wait>')).timeline
    assert tl.one("flap").outcome == "failed" and tl.one("nod").outcome == "cancelled"
    assert tl.by_path("wait[0]").end == pytest.approx(0.2)


async def test_async_until_any_in_sync_first_mode():
    tl = (await _shell(mode="sync-first").run_text('<async until="any"><nod/><flap/></async><smile/>')).timeline
    assert tl.one("nod").outcome == "cancelled" and tl.one("nod").end == 0.5 and tl.one("smile").start == 0.5


async def test_nested_scopes():
    """A nested scope is a barrier (the paper's <wait>): the nod after it waits; the inner
    scope's timeout is its end, which ends the outer any-scope."""
    prog = '<wait until="any"><wait timeout="1"><walk/></wait><nod/></wait><smile/>'
    tl = (await _shell().run_text(prog)).timeline
    inner, outer = tl.by_path("wait[0]/wait[0]"), tl.by_path("wait[0]")
    assert (inner.outcome, inner.end) == ("timeout", 1)
    assert (outer.outcome, outer.end, outer.ended_by) == ("done", 1, "wait[0]/wait[0]")
    assert tl.one("walk").outcome == "cancelled" and tl.one("walk").end == 1
    assert tl.one("nod").outcome == "cancelled" and tl.one("nod").start is None
    assert tl.one("smile").start == 1


# -- timeout -----------------------------------------------------------------------------------

async def test_timeout_ends_the_scope_and_says_so():
    r = await _shell().run_text('<wait timeout="1"><walk d="3"/></wait><smile/>')
    tl = r.timeline
    w, walk = tl.by_path("wait[0]"), tl.one("walk")
    assert (w.outcome, w.end, w.ended_by, w.args) == ("timeout", 1, "timeout", {"timeout": 1.0})
    assert (walk.outcome, walk.end) == ("cancelled", 1)
    assert tl.one("smile").start == 1
    assert any(o.kind == "info" and '<wait timeout="1"> timed out after 1 s' in o.message for o in r.observations)


async def test_timeout_not_reached_is_done():
    tl = (await _shell().run_text('<async until="all" timeout="5"><walk d="3"/></async>')).timeline
    assert tl.by_path("async[0]").outcome == "done" and tl.by_path("async[0]").end == 3
    assert tl.one("walk").outcome == "done"


async def test_timeout_counts_from_the_scopes_start_and_cancels_late_children():
    sh = _shell()
    r = await sh.run(timed_stream([(0, '<walk d="2"/><wait timeout="1.5"><flap/>'), (4, "<wave/>"), (5, "</wait>")]))
    tl = r.timeline
    w = tl.by_path("wait[0]")
    assert w.start == 2 and w.end == 3.5 and w.outcome == "timeout"  # after the barrier: 2 + 1.5
    assert tl.one("wave").start is None and tl.one("wave").outcome == "cancelled"


async def test_timeout_sleeps_on_the_shells_clock():
    """``Shell(sleep=...)``: the runtime's board-clock sleep is what a timeout waits on."""
    asked = []

    async def board_sleep(seconds: float) -> None:
        asked.append(seconds)
        await anyio.sleep(seconds / 2)  # a board clock running at twice the event loop's speed

    tl = (await _shell(sleep=board_sleep).run_text('<wait timeout="1"><walk/></wait>')).timeline
    assert asked == [1.0] and tl.by_path("wait[0]").end == 0.5


async def test_a_failing_clock_fails_the_scope_not_the_run():
    async def broken(seconds: float) -> None:
        raise RuntimeError("link lost")

    r = await _shell(sleep=broken).run_text('<wait timeout="1"><walk/></wait><smile/>')
    tl = r.timeline
    w = tl.by_path("wait[0]")
    assert w.outcome == "failed" and w.error == "timeout clock failed: RuntimeError: link lost" and w.end == 3
    assert tl.one("walk").outcome == "done" and tl.one("smile").start == 3


async def test_interrupting_a_timed_scope_cancels_its_timer():
    sh = _shell()
    out = {}

    async def run():
        out["r"] = await sh.run_text('<wait timeout="10"><walk d="30"/></wait>')

    async with anyio.create_task_group() as tg:
        tg.start_soon(run)
        await anyio.sleep(2)
        sh.interrupt()
    w = out["r"].timeline.by_path("wait[0]")
    assert w.outcome == "interrupted" and w.end == 2 and w.ended_by is None


# -- bad input: one clear line, a failed scope, nothing hangs ------------------------------------

BAD = {
    '<wait until="some">': "<wait> until='some' is not one of 'all', 'any'",
    '<wait until="flow">': "<wait> until='flow' is not one of 'all', 'any' (until=\"flow\" is not supported)",
    '<async until="">': "<async> until='' is not one of 'all', 'any'",
    '<wait timeout="-1">': "<wait> timeout='-1' is out of range: seconds, more than 0 and at most 600",
    '<wait timeout="0">': "<wait> timeout='0' is out of range",
    '<wait timeout="abc">': "<wait> timeout='abc' is not a number",
    '<wait timeout="nan">': "<wait> timeout='nan' is not a finite number",
    '<wait timeout="inf">': "<wait> timeout='inf' is not a finite number",
    '<wait timeout="1e9">': "<wait> timeout='1e9' is out of range: seconds, more than 0 and at most 600",
}


@pytest.mark.parametrize("tag", sorted(BAD))
async def test_bad_scope_attributes_fail_the_scope_with_one_line(tag):
    name = tag[1:].split()[0]
    r = await _shell().run_text(f'{tag}<nod d="1"/><flap/></{name}><smile/>')
    tl = r.timeline
    scope = tl.by_path(f"{name}[0]")
    assert scope.outcome == "failed" and scope.error.startswith(BAD[tag]), scope.error
    assert "\n" not in scope.error and errors(r) == [scope.error]
    # it still scopes its children as a plain scope would (until="all", no timeout): a barrier
    assert tl.one("nod").outcome == tl.one("flap").outcome == "done"
    assert tl.one("smile").start == 1


async def test_until_flow_says_it_is_not_supported():
    r = await _shell().run_text('<wait until="flow"><flap/></wait>')
    assert errors(r)[0].endswith('(until="flow" is not supported)')


async def test_bad_self_closing_scope_is_a_failed_call():
    r = await _shell().run_text('<walk d="1"/><wait timeout="-1"/><smile/>')
    tl = r.timeline
    assert tl.by_path("wait[0]").outcome == "failed" and len(errors(r)) == 1
    assert tl.one("smile").start == 0  # no barrier was made


async def test_self_closing_scope_attributes_have_no_effect_and_say_so():
    r = await _shell().run_text('<walk d="1"/><wait until="any" timeout="0.1"/><smile/>')
    assert r.timeline.one("smile").start == 1  # still the paper's barrier
    assert any(o.kind == "warning" and "has no children: timeout and until has no effect" in o.message
               for o in r.observations)


async def test_other_scope_attributes_are_ignored_with_a_warning():
    r = await _shell().run_text('<wait until="any" colour="red"><flap/></wait>')
    assert r.timeline.by_path("wait[0]").outcome == "done"
    assert any("<wait> takes only until and timeout; ignored ['colour']" in o.message for o in r.observations)


async def test_the_timeout_bound_is_a_limit():
    sh = _shell(limits=TurnLimits(max_scope_timeout_s=2.0))
    r = await sh.run_text('<wait timeout="3"><flap/></wait>')
    assert errors(r) == ["<wait> timeout='3' is out of range: seconds, more than 0 and at most 2"]
    with pytest.raises(ValueError, match="max_scope_timeout_s"):
        TurnLimits(max_scope_timeout_s=float("nan")).validate()


async def test_scopes_nested_past_the_limit():
    """70 any-scopes nested in a timed scope: the elements past MAX_DEPTH are refused with one
    line each, and nothing hangs past the outer timeout."""
    n = MAX_DEPTH + 6
    prog = ('<wait timeout="2"><walk d="30"/>' + '<wait until="any">' * n + "<flap/>" + "</wait>" * n
            + "</wait><smile/>")
    r = await _shell().run_text(prog)
    tl = r.timeline
    deep = [e for e in errors(r) if "nested deeper" in e]
    assert len(deep) == (n + 2) - MAX_DEPTH  # the waits and the flap below depth 64
    assert deep[0] == f"<wait> is nested deeper than {MAX_DEPTH} elements; refused" and len(errors(r)) == len(deep)
    assert tl.one("walk").outcome == "cancelled" and tl.one("walk").end == 2
    assert tl.by_path("wait[0]").outcome == "timeout" and tl.one("smile").start == 2


# -- RUN: a skill's calls are its children -----------------------------------------------------

async def _saved(sh, *skills: tuple[str, str]):
    for name, program in skills:
        await sh.run_text(f'<SAVE name="{name}">{program}</SAVE>')
    return sh


async def test_run_calls_are_children_of_the_run():
    sh = await _saved(_shell(skills=SkillStore()), ("greet", '<nod d="1"/><flap/>'))
    r = await sh.run_text('<walk d="1"/><RUN id="greet"/><RUN id="greet"/>')
    tl = r.timeline
    assert [x.path for x in tl] == ["walk[0]", "RUN[0]", "RUN[0]/nod[0]", "RUN[0]/flap[0]",
                                    "RUN[1]", "RUN[1]/nod[0]", "RUN[1]/flap[0]"]
    run0, run1 = tl.by_path("RUN[0]"), tl.by_path("RUN[1]")
    assert run0.outcome == "done" and (run0.start, run0.end) == (0, 1)  # completes when its calls have
    assert tl.by_path("RUN[1]/nod[0]").start == 1  # the same channel queue as if written inline
    assert run1.end == 2


async def test_nested_runs_and_a_run_start_tag():
    sh = await _saved(_shell(skills=SkillStore()), ("a", "<flap/>"), ("b", '<RUN id="a"/><nod d="1"/>'))
    tl = (await sh.run_text('<RUN id="b"><smile/></RUN>')).timeline
    assert [x.path for x in tl] == ["RUN[0]", "RUN[0]/RUN[0]", "RUN[0]/RUN[0]/flap[0]", "RUN[0]/nod[0]",
                                    "RUN[0]/smile[0]"]
    assert all(x.outcome == "done" for x in tl) and tl.by_path("RUN[0]").end == 1


async def test_a_run_in_an_any_scope_is_cancelled_with_its_calls():
    sh = await _saved(_shell(skills=SkillStore()), ("routine", '<walk d="3"/><nod d="3"/>'))
    tl = (await sh.run_text('<wait until="any"><RUN id="routine"/><flap/></wait>')).timeline
    assert tl.by_path("wait[0]/RUN[0]").outcome == "cancelled"
    assert tl.by_path("wait[0]/RUN[0]/walk[0]").outcome == "cancelled"
    assert tl.by_path("wait[0]/RUN[0]/nod[0]").end == 0.5
    # and the other way round: the RUN ends first and cancels the sibling
    sh2 = await _saved(_shell(skills=SkillStore()), ("quick", '<flap/>'))
    tl = (await sh2.run_text('<wait until="any"><walk/><RUN id="quick"/></wait>')).timeline
    assert tl.by_path("wait[0]").ended_by == "wait[0]/RUN[0]" and tl.one("walk").outcome == "cancelled"


async def test_interrupting_reaches_a_runs_calls():
    sh = await _saved(_shell(skills=SkillStore()), ("routine", '<walk d="3"/><wave/>'))
    out = {}

    async def run():
        out["r"] = await sh.run_text('<RUN id="routine"/>')

    async with anyio.create_task_group() as tg:
        tg.start_soon(run)
        await anyio.sleep(1)
        assert sh.interrupt() == 3  # the RUN, its running walk and its queued wave
    tl = out["r"].timeline
    assert {x.path: x.outcome for x in tl} == {"RUN[0]": "interrupted", "RUN[0]/walk[0]": "interrupted",
                                               "RUN[0]/wave[0]": "interrupted"}
    assert tl.by_path("RUN[0]").end == 1


async def test_a_failed_run_is_as_before():
    tl = (await _shell(skills=SkillStore()).run_text('<RUN id="nope"/><flap/>')).timeline
    run = tl.by_path("RUN[0]")
    assert run.outcome == "failed" and "unknown skill" in run.error and tl.one("flap").start == 0
