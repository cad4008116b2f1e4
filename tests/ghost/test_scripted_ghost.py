"""ScriptedGhost and the tokeniser, on Trio's virtual clock."""

from __future__ import annotations

import math

import hypothesis.strategies as st
import pytest
import trio
import trio.testing
from hypothesis import given

from host.ghost import GhostError, ScriptedGhost, make_ghost, tokenize

PROGRAM = (
    'Hello! I am CoCo. <head_act action="nod" duration="3.5"/>'
    "<wait><wave/></wait> 你好，我们一起做运动吧！<chest_expansion_exercise/>"
)


def run_virtual(afn, *args):  # type: ignore[no-untyped-def]
    return trio.run(afn, *args, clock=trio.testing.MockClock(autojump_threshold=0))


async def timed_chunks(ghost: ScriptedGhost) -> list[tuple[float, str]]:
    t0 = trio.current_time()
    return [(trio.current_time() - t0, c) async for c in ghost.stream([])]


def test_tokens_look_like_llm_tokens() -> None:
    assert tokenize('<head_act action="nod"/>') == ["<", "head", "_act", " action", '="', "nod", '"/>']
    assert tokenize("3.5") == ["3", ".", "5"]
    assert all(1 <= len(t) <= 2 for t in tokenize("你好我们一起做运动"))


def test_tokens_average_three_to_four_chars_on_the_paper_tasks() -> None:
    programs = [  # paper tasks 5, 14, 23, 24
        '<wait><head_act action="nod"/></wait><wave/>',
        'Hello<face_emo emo="smile"/>',
        '<head_act action="nod"><move_strides direction="backward" times="3"/></head_act>',
        '<shake_ass><play_bgm duration="10"/><face_emo emo="calm" duration="3"/></shake_ass>',
    ]
    text = "".join(programs)
    n = sum(len(tokenize(p)) for p in programs)
    assert 2.5 <= len(text) / n <= 4.5


@given(st.text())
def test_tokenize_round_trips_any_text(text: str) -> None:
    tokens = tokenize(text)
    assert "".join(tokens) == text
    assert all(tokens)


def test_chunks_concatenate_to_the_program_at_the_configured_rate() -> None:
    ghost = ScriptedGhost(PROGRAM, tokens_per_s=30.0, jitter=0.0)
    out = run_virtual(timed_chunks, ghost)
    assert "".join(c for _, c in out) == PROGRAM
    assert [c for _, c in out] == tokenize(PROGRAM)
    # without jitter, token i arrives at exactly (i + 1) / 30 s of virtual time
    assert [t for t, _ in out] == pytest.approx([(i + 1) / 30.0 for i in range(len(out))])


def test_jitter_is_bounded_seeded_and_keeps_the_mean_rate() -> None:
    program = PROGRAM * 20
    ghost = ScriptedGhost(program, tokens_per_s=40.0, jitter=0.2, seed=7)
    out = run_virtual(timed_chunks, ghost)
    times = [t for t, _ in out]
    gaps = [b - a for a, b in zip([0.0, *times], times)]
    assert gaps == pytest.approx(ghost.gaps())
    assert all(0.8 / 40 - 1e-9 <= g <= 1.2 / 40 + 1e-9 for g in gaps)
    assert len(set(round(g, 9) for g in gaps)) > 10  # really jittered
    assert times[-1] == pytest.approx(len(out) / 40.0, rel=0.03)
    assert ScriptedGhost(program, 40.0, 0.2, seed=7).gaps() == ghost.gaps()
    assert ScriptedGhost(program, 40.0, 0.2, seed=8).gaps() != ghost.gaps()
    assert "".join(c for _, c in out) == program


@pytest.mark.parametrize("rate", [0.0, math.inf])
def test_unpaced_mode_takes_no_virtual_time(rate: float) -> None:
    out = run_virtual(timed_chunks, ScriptedGhost(PROGRAM, tokens_per_s=rate))
    assert "".join(c for _, c in out) == PROGRAM
    assert all(t == 0.0 for t, _ in out)


def test_injected_sleep_is_used() -> None:
    slept: list[float] = []

    async def fake_sleep(s: float) -> None:
        slept.append(s)

    ghost = ScriptedGhost("<wave/>", tokens_per_s=10.0, jitter=0.0, sleep=fake_sleep)
    assert run_virtual(ghost.complete, []) == "<wave/>"
    assert slept == pytest.approx([0.1] * len(tokenize("<wave/>")))


def test_consumer_can_stop_and_cancel_midway() -> None:
    async def main() -> tuple[list[str], float]:
        got: list[str] = []
        with trio.move_on_after(0.5):
            async for c in ScriptedGhost(PROGRAM * 5, tokens_per_s=10.0, jitter=0.0).stream([]):
                got.append(c)
        return got, trio.current_time()

    got, now = run_virtual(main)
    assert len(got) == 4 and now == pytest.approx(0.5)  # tokens at 0.1..0.4 s, cut at 0.5 s


def test_stream_can_be_replayed() -> None:
    ghost = ScriptedGhost(PROGRAM, tokens_per_s=math.inf)
    assert run_virtual(ghost.complete, []) == run_virtual(ghost.complete, []) == PROGRAM


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"tokens_per_s": -1.0}, "tokens_per_s"), ({"tokens_per_s": math.nan}, "tokens_per_s"), ({"jitter": 1.5}, "jitter")],
)
def test_bad_parameters_are_clear_errors(kwargs: dict[str, float], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        ScriptedGhost("x", **kwargs)  # type: ignore[arg-type]


def test_make_ghost_specs() -> None:
    g = make_ghost("scripted", program="<wave/>", tokens_per_s=None, seed=3)
    assert isinstance(g, ScriptedGhost) and g.tokens_per_s == 30.0 and g.seed == 3
    o = make_ghost("openai:deepseek-chat", base_url="http://127.0.0.1:9/v1", api_key="k", program="ignored")
    assert o.name == "openai:deepseek-chat"
    with pytest.raises(GhostError, match="needs a program"):
        make_ghost("scripted")
    with pytest.raises(GhostError, match=r"unknown LLM spec 'claude:x'.*scripted, openai:MODEL"):
        make_ghost("claude:x")
    with pytest.raises(GhostError, match="takes no argument"):
        make_ghost("scripted:fast", program="x")
