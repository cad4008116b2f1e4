"""Scheduler semantics on the virtual clock: the paper's four execution patterns
(exact start/end times), streaming dispatch, interruption, lifecycles, failures."""

from __future__ import annotations

import anyio
import pytest

from host.shell.context import CallContext
from host.shell.registry import Registry
from host.shell.shell import Shell
from host.shell.types import Module, shell_function

from support.shell_fakes import LOG, fake, shell_with, timed_stream

pytestmark = pytest.mark.anyio



def spans(result):
    return {r.function: (r.start, r.end) for r in result.timeline}


async def test_pattern_sequential():
    sh = shell_with({"C1": [fake("F1", 2), fake("F2", 1.5), fake("F3", 1.5)]})
    r = await sh.run_text("<F1/><F2/><F3/>")
    assert spans(r) == {"F1": (0, 2), "F2": (2, 3.5), "F3": (3.5, 5)}


async def test_pattern_parallel_with_streaming_dispatch():
    sh = shell_with({"C1": [fake("F1", 4)], "C2": [fake("F2", 5)], "C3": [fake("F3", 3)]})
    r = await sh.run(timed_stream([(0.5, "<F2/>"), (1.0, "<F1/>"), (2.0, "<F3/>")]))
    assert spans(r) == {"F1": (1, 5), "F2": (0.5, 5.5), "F3": (2, 5)}
    assert [rec.dispatch for rec in r.timeline] == [0.5, 1.0, 2.0]


async def test_pattern_lifecycle_scoped_termination():
    sh = shell_with({"C1": [fake("F1", 1)], "C2": [fake("F2", 2.5), fake("F4", 1)], "C3": [fake("F3", 4)]})
    r = await sh.run(timed_stream([(0.5, "<F1><F2/>"), (1.5, "<F3/>"), (2.0, "<F4/></F1>")]))
    assert spans(r) == {"F1": (0.5, 5.5), "F2": (0.5, 3), "F4": (3, 4), "F3": (1.5, 5.5)}
    assert r.timeline.one("F1").persistent


async def test_pattern_external_interruption():
    sh = shell_with({"C1": [fake("F1", 100)], "C2": [fake("F2", 100)]})

    async def stream():
        yield "<F1/>"
        await anyio.sleep(0.5)
        yield "<F2/>"
        await anyio.sleep(100)  # the LLM is still "generating"
        yield "<F1/>"

    async with anyio.create_task_group() as tg:
        out = {}

        async def run():
            out["r"] = await sh.run(stream())

        tg.start_soon(run)
        await anyio.sleep(5.5)
        assert sh.interrupt() == 2
    r = out["r"]
    assert spans(r) == {"F1": (0, 5.5), "F2": (0.5, 5.5)}
    assert {rec.outcome for rec in r.timeline} == {"interrupted"} and r.interrupted
    assert len(r.timeline) == 2  # the rest of the stream was not dispatched


async def test_interrupt_reaches_queued_calls_and_resets_parents():
    LOG.clear()
    sh = shell_with({"C1": [fake("P", 1, reset_seconds=0.25), fake("A", 3), fake("B", 3)], "C2": [fake("Q", 10)]})
    async with anyio.create_task_group() as tg:
        out = {}

        async def run():
            out["r"] = await sh.run_text("<Q/><P><A/></P><B/>")

        tg.start_soon(run)
        await anyio.sleep(1)
        assert sh.interrupt(["C1"]) == 3  # P (active parent), A (running, same channel), B (queued)
    tl = out["r"].timeline
    assert tl.one("Q").outcome == "done" and tl.one("Q").end == 10
    assert tl.one("A").outcome == "interrupted" and tl.one("A").end == 1
    assert tl.one("B").outcome == "interrupted" and tl.one("B").start is None
    p = tl.one("P")
    assert p.outcome == "interrupted" and p.end == 1.25  # reset hook (0.25 s) ran, shielded
    assert any(e == "P:reset" and t == pytest.approx(1.25) for t, e in LOG)


async def test_interrupt_while_waiting_for_stream_and_before_deps():
    """Cancellation reaches calls waiting on dependencies, independent of arrival order."""
    sh = shell_with({"C1": [fake("A", 5)], "C2": [fake("B", 1)]})

    async def stream():
        yield "<wait><A/></wait><B/>"  # B is dispatched but waits for the barrier
        await anyio.sleep_forever()

    async with anyio.create_task_group() as tg:
        out = {}

        async def run():
            out["r"] = await sh.run(stream())

        tg.start_soon(run)
        await anyio.sleep(2)
        sh.interrupt()
    tl = out["r"].timeline
    assert tl.one("B").outcome == "interrupted" and tl.one("B").start is None
    assert tl.one("A").end == 2 and tl.one("wait").end == 2


async def test_reset_finishes_before_next_activation_on_same_channel():
    LOG.clear()
    sh = shell_with({"C1": [fake("P", 1, reset_seconds=0.5), fake("A", 1)], "C2": [fake("X", 2)]})
    r = await sh.run_text("<P><X/></P><P><X/></P><A/>")
    p1, p2 = r.timeline.find("P")
    assert (p1.start, p1.end) == (0, 2.5)  # children done at 2, reset takes 0.5
    assert p2.start == 2.5 and p2.end == 5.0
    assert r.timeline.one("A").start == 5.0


async def test_same_channel_descendant_runs_at_once_and_overrides():
    seen = []

    @shell_function
    async def hold(ctx: CallContext) -> None:
        while True:
            seen.append((anyio.current_time(), ctx.overridden))
            await anyio.sleep(1)

    @shell_function
    async def step() -> None:
        await anyio.sleep(2.5)

    sh = Shell(Registry([Module.from_functions("body", hold, step)]))
    t0 = anyio.current_time()
    r = await sh.run_text("<hold><step/></hold>")
    assert spans(r) == {"hold": (0, 2.5), "step": (0, 2.5)}
    # at t=0 both start in the same scheduler batch (order unspecified); afterwards hold is overridden
    assert [(t - t0, o) for t, o in seen][1:] == [(1, True), (2, True)]


async def test_wait_is_a_barrier_for_earlier_calls_but_not_ancestors():
    sh = shell_with({"C1": [fake("A", 3), fake("P", 1)], "C2": [fake("B", 1)]})
    r = await sh.run_text("<A/><wait><B/></wait><P><wait><B/></wait></P>")
    b1, b2 = r.timeline.find("B")
    assert b1.start == 3  # barrier: after A
    p = r.timeline.one("P")
    assert p.start == 4 and b2.start == 4 and p.end == 5  # inner wait does not wait for its ancestor P


async def test_sync_attribute_puts_call_on_main_channel():
    sh = shell_with({"C1": [fake("A", 2)], "C2": [fake("B", 1)]})
    r = await sh.run_text('<A sync="true"/><B/>')
    a, b = r.timeline.one("A"), r.timeline.one("B")
    assert a.channel == "main" and b.start == 2
    r = await sh.run_text("<A/><B/>")
    assert r.timeline.one("B").start == 0


async def test_a_refused_argument_fails_in_one_line_without_an_exception_name():
    """A function that refuses its arguments (ValueError) fails with its own message; any other
    exception is a bug and keeps its class name."""

    @shell_function
    async def reach(deg: float = 0) -> None:
        raise ValueError(f"elbow_flex reaches -97..97 deg, not {deg:g}")

    @shell_function
    async def buggy() -> None:
        raise KeyError("servo")

    sh = Shell(Registry([Module.from_functions("C1", reach, buggy)]))
    r = await sh.run_text('<reach deg="500"/><buggy/>')
    assert r.timeline.one("reach").error == "elbow_flex reaches -97..97 deg, not 500"
    assert r.timeline.one("buggy").error == "KeyError: 'servo'"


async def test_failure_is_local():
    @shell_function
    async def boom(x: int = 1) -> None:
        await anyio.sleep(1)
        raise RuntimeError("servo stalled")

    sh = Shell(Registry([Module.from_functions("C1", boom, fake("A", 1)), Module.from_functions("C2", fake("B", 1))]))
    r = await sh.run_text("<boom><B/></boom><A/><nope/><B/>")
    tl = r.timeline
    assert tl.one("boom").outcome == "failed" and "servo stalled" in tl.one("boom").error
    assert tl.one("boom").end == 1  # its child B still ran to completion
    assert [x.outcome for x in tl.find("B")] == ["done", "done"]
    assert tl.one("A").start == 1  # after boom's lifecycle on C1
    assert tl.one("nope").outcome == "failed"
    assert any("servo stalled" in o.message for o in r.observations)
    assert any("unknown function <nope>" in o.message for o in r.observations)


async def test_speech_is_flushed_at_sentence_boundaries_while_streaming():
    spoken = []

    @shell_function(speech=True)
    async def speak(text: str) -> None:
        spoken.append((anyio.current_time(), text))
        await anyio.sleep(0.1 * len(text))

    sh = Shell(Registry([Module.from_functions("speech", speak)]))
    t0 = anyio.current_time()
    r = await sh.run(timed_stream([(0, "Hello there. How a"), (5, "re you? 价格是3.5元。"), (9, "  \n"), (10, "Bye")]))
    # A terminator at the end of what has arrived is decided by the next character (so the split
    # never depends on chunking: "。" may still be followed by a closing quote), here at t=9.
    assert [(t - t0, s) for t, s in spoken] == [
        (0, "Hello there."), (5, "How are you?"), (9, "价格是3.5元。"), (10, "Bye")]
    assert len(r.timeline) == 4


async def test_text_first_class_blocks_on_main_channel():
    @shell_function(speech=True)
    async def speak(text: str) -> None:
        await anyio.sleep(1)

    reg = Registry([Module.from_functions("speech", speak), Module.from_functions("C1", fake("A", 1))])
    r = await Shell(reg, text_first_class=True).run_text("Hi.<A/>")
    assert r.timeline.one("speak").channel == "main" and r.timeline.one("A").start == 1
    r = await Shell(reg).run_text("Hi.<A/>")
    assert r.timeline.one("A").start == 0


async def test_results_become_observations_and_clock_is_injectable():
    @shell_function
    async def look() -> str:
        await anyio.sleep(1)
        return "a red ball"

    ticks = iter(range(100))
    sh = Shell(Registry([Module.from_functions("camera", look)]), clock=lambda: float(next(ticks)))
    r = await sh.run_text("<look/>")
    assert "a red ball" in r.observation_text()
    rec = r.timeline.one("look")
    assert rec.result == "a red ball" and rec.start < rec.end  # times come from the injected clock


async def test_outer_cancellation_cancels_everything():
    sh = shell_with({"C1": [fake("A", 10)]})
    with anyio.move_on_after(2):
        await sh.run_text("<A/>")
    assert not sh.running


async def test_strict_parse_error_stops_dispatch_and_cancels():
    sh = shell_with({"C1": [fake("A", 10), fake("B", 1)]})
    r = await sh.run(timed_stream([(0, "<A/>"), (1, "<B></C>"), (2, "<B/>")]))
    assert r.error is not None and r.error.line == 1
    assert r.timeline.one("A").outcome == "cancelled" and r.timeline.one("A").end == 1
    assert not r.timeline.find("B") or all(x.outcome == "cancelled" for x in r.timeline.find("B"))
    assert any("parse error" in o.message for o in r.observations)


async def test_strict_unclosed_element_at_close_is_an_error():
    sh = shell_with({"C1": [fake("A", 1)]})
    r = await sh.run_text("<A>")
    assert r.error is not None and r.timeline.one("A").outcome == "cancelled"


async def test_lenient_mode_recovers_with_warnings():
    sh = shell_with({"C1": [fake("A", 1)], "C2": [fake("B", 1)]}, strict=False)
    r = await sh.run_text("<A><B/></X></A> 1 < 2 <B/><A>")
    assert r.error is None
    assert [x.outcome for x in r.timeline] == ["done"] * len(r.timeline)
    assert len(r.timeline.find("A")) == 2 and len(r.timeline.find("B")) == 2
    assert sum(o.kind == "warning" for o in r.observations) >= 2


async def test_run_is_not_reentrant():
    sh = shell_with({"C1": [fake("A", 1)]})
    async with anyio.create_task_group() as tg:
        tg.start_soon(sh.run_text, "<A/>")
        await anyio.sleep(0.5)
        with pytest.raises(RuntimeError):
            await sh.run_text("<A/>")


def handing_over(name: str, seconds: float, lead: float):
    """A call that hands its channel over ``lead`` s before it ends (as the motion runtime does)."""

    @shell_function(name=name)
    async def fn(ctx: CallContext) -> None:
        LOG.append((anyio.current_time(), f"{name}:start"))
        await anyio.sleep(seconds - lead)
        ctx.hand_over()
        await anyio.sleep(lead)

    return fn


async def test_hand_over_lets_the_next_call_on_the_channel_start_early():
    sh = shell_with({"C1": [handing_over("F1", 2, 0.5), handing_over("F2", 1, 0.25), fake("F3", 1)],
                     "C2": [fake("G", 1)]})
    r = await sh.run_text("<F1/><F2/><F3/><wait><G/></wait>")
    s = spans(r)
    assert s["F1"] == (0, 2) and s["F2"] == (1.5, 2.5) and s["F3"] == (2.25, 3.25)  # done still at the real end
    assert s["G"] == (3.25, 4.25)  # the main channel still waits for completion, not hand-over


async def test_interrupt_cancels_a_call_started_by_hand_over():
    sh = shell_with({"C1": [handing_over("F1", 2, 0.5), fake("F2", 1)]})

    async def stream():
        yield "<F1/><F2/>"
        await anyio.sleep(1.7)
        sh.interrupt(["C1"])

    r = await sh.run(stream())
    assert r.timeline.one("F2").start == 1.5 and r.timeline.one("F2").outcome == "interrupted"


async def test_parser_class_parses_the_stream_and_only_the_stream():
    """``Shell.parser_class`` is the type of the run's stream parser (made once per run, with the
    shell's strictness); a skill's program is still parsed by the plain strict parser."""
    from host.shell.parser import FunctionTokenParser

    made: list[tuple[str, bool]] = []

    class Counting(FunctionTokenParser):
        def __init__(self, strict: bool = True) -> None:
            super().__init__(strict)
            made.append(("Counting", strict))

    class CountingShell(Shell):
        parser_class = Counting

    program = '<SAVE name="twice"><A/><A/></SAVE><RUN id="twice"/>'
    sh = CountingShell(Registry([Module.from_functions("C1", fake("A", 1))]), strict=False)
    r = await sh.run_text(program)
    assert made == [("Counting", False)]
    assert [x.outcome for x in r.timeline.find("A")] == ["done", "done"]
    plain = await shell_with({"C1": [fake("A", 1)]}, strict=False).run_text(program)
    assert [(x.path, x.start, x.end) for x in r.timeline] == [(x.path, x.start, x.end) for x in plain.timeline]


async def test_the_stream_is_closed_when_the_run_stops_reading_early():
    """A stream the run stops reading (a strict parse error) is closed, shielded; an exhausted async
    generator has nothing to close; any other async iterator is closed at the end as before."""
    events: list[str] = []

    async def stream():
        try:
            yield "<A/>"
            yield "<B></C>"
            yield "<A/>"
        finally:
            events.append("generator closed")

    class Stream:
        def __init__(self, parts: list[str]) -> None:
            self.parts = parts

        def __aiter__(self):
            return self

        async def __anext__(self) -> str:
            if not self.parts:
                raise StopAsyncIteration
            return self.parts.pop(0)

        async def aclose(self) -> None:
            await anyio.sleep(1)  # shielded: the run's cancellation does not cut it short
            events.append("iterator closed")

    sh = shell_with({"C1": [fake("A", 1), fake("B", 1)]})
    r = await sh.run(stream())
    assert r.error is not None and events == ["generator closed"]
    r = await sh.run(Stream(["<A/>", "<B></C>", "<A/>"]))
    assert r.error is not None and events == ["generator closed", "iterator closed"]
    r = await sh.run(Stream(["<A/>"]))
    assert r.error is None and events[-1] == "iterator closed" and len(events) == 3


async def test_a_forced_stop_cuts_the_shielded_resets_short():
    """A second Ctrl-C 50 ms after the first waited ~5 s (``RESET_TIMEOUT``) on ``ghostshell run --task
    26``: the first had interrupted the turn, whose resets run shielded, and the second cancelled the
    turn but not them. ``Shell.abort_cleanups`` cuts the running resets short and skips later ones."""
    from host.shell.scheduler import RESET_TIMEOUT

    LOG.clear()
    sh = shell_with({"C1": [fake("P", 1, reset_seconds=60.0), fake("A", 3)]})
    async with anyio.create_task_group() as tg:
        out = {}

        async def run():
            out["r"] = await sh.run_text("<P><A/></P>")

        tg.start_soon(run)
        await anyio.sleep(1)
        assert sh.interrupt() == 2  # the first signal: P's reset starts (60 s, shielded)
        await anyio.sleep(0.05)
        t_forced = anyio.current_time()
        sh.abort_cleanups()  # the second, 50 ms later
    p = out["r"].timeline.one("P")
    assert anyio.current_time() - t_forced < 0.01 < RESET_TIMEOUT  # the run ended at once
    assert p.outcome == "interrupted" and p.error is None and p.end == pytest.approx(1.05), p  # not "failed"
    assert not any(e == "P:reset" for _, e in LOG)  # the reset never finished
