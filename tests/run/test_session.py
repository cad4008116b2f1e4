"""RobotSession: one lockstep board and one shell across several turns; executed text; interruption."""

from __future__ import annotations

from pathlib import Path

import anyio
import pytest

from host.run.robot_session import RobotSession, SessionOptions, TurnResult
from host.shell.skills import SkillStore


def _session(tmp_path: Path, **kw: object) -> RobotSession:
    return RobotSession(SessionOptions(out=tmp_path, lockstep=True, **kw))  # type: ignore[arg-type]


def test_turns_share_board_shell_and_skills(tmp_path: Path) -> None:
    async def main() -> tuple[list[TurnResult], dict]:
        async with _session(tmp_path, skills=SkillStore(tmp_path / "skills.json")) as s:
            t1 = await s.run_turn('<SAVE name="greet"><head_act action="nod"/></SAVE>Hi.', settle_s=0.1)
            t2 = await s.run_turn('<RUN id="greet"/>', settle_s=0.1)
            return [t1, t2], s.state()

    (t1, t2), state = anyio.run(main, backend="asyncio")
    assert t1.summary.outcome == "done" and t2.summary.outcome == "done", t2.result.timeline.table()
    assert t2.result.timeline.one("head_act").outcome == "done"
    assert t2.board_t0 > t1.board_t0  # one board clock across turns
    assert "greet" in state["skills"] and not state["fell"]
    for t in (t1, t2):
        assert (t.out / "timeline.json").exists() and (t.out / "summary.json").exists()
    assert t1.out != t2.out
    assert t1.executed_text.startswith('<SAVE name="greet">') and t1.executed_text.endswith("Hi.")
    assert t2.executed_text == '<RUN id="greet"/>'  # the skill's body is not repeated


def test_interrupted_turn_keeps_only_what_ran(tmp_path: Path) -> None:
    program = ('<head_act action="nod"><move_strides direction="forward" times="6"/></head_act>'
               '<wait><wave/></wait>Never said.')

    async def main() -> TurnResult:
        async with _session(tmp_path) as s:
            return await s.run_turn(program, interrupt_after=1.0, settle_s=0.1)

    turn = anyio.run(main, backend="asyncio")
    assert turn.interrupted and turn.summary.outcome == "interrupted"
    text = turn.executed_text
    assert text.startswith('<head_act action="nod"><move_strides')
    assert "Never said" not in text
    assert turn.received_text == program



def test_a_session_plans_every_behaviour_once_before_its_first_turn(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """One-time planning costs (CoCo's gait calibration file) are paid before the link connects (CPU
    work that would hold the heartbeat back once the board's watchdog is armed), not by the first
    call's token -> servo path; the warm-up plans every behaviour that has defaults."""
    import host.run.robot_session as session_module
    from robots.coco.gaits import load_calibration

    load_calibration.cache_clear()
    at_connect: list[int] = []
    connect = session_module.BoardClient.connect

    async def connect_and_note(*args: object, **kw: object) -> object:
        at_connect.append(load_calibration.cache_info().currsize)
        return await connect(*args, **kw)  # type: ignore[arg-type]

    async def main() -> int:
        async with _session(tmp_path) as s:
            assert load_calibration.cache_info().currsize == 1  # read before any turn
            return s.runtime.warm_up()

    monkeypatch.setattr(session_module.BoardClient, "connect", connect_and_note)
    planned = anyio.run(main, backend="asyncio")
    assert at_connect == [1]  # planned before the link came up
    assert planned >= 20  # CoCo: all 24 but joint_move, which needs its joints


def test_a_session_sets_up_plotting_before_its_link_connects(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The turn's plots are drawn in a worker thread while the link is live; matplotlib's import and
    first draw (hundreds of ms in which the loop thread barely got the GIL: a realtime board's
    watchdog latched in CI) happen before the link connects (``artefacts.warm_up_plotting``)."""
    import host.run.robot_session as session_module

    order: list[str] = []
    connect = session_module.BoardClient.connect
    warm = session_module.artefacts.warm_up_plotting

    def warm_and_note() -> None:
        order.append("plotting")
        warm()

    async def connect_and_note(*args: object, **kw: object) -> object:
        order.append("connect")
        return await connect(*args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(session_module.artefacts, "warm_up_plotting", warm_and_note)
    monkeypatch.setattr(session_module.BoardClient, "connect", connect_and_note)

    async def main() -> None:
        async with _session(tmp_path):
            pass

    anyio.run(main, backend="asyncio")
    assert order == ["plotting", "connect"]
