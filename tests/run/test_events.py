"""Events that interrupt (issue 19 item 3): detection, policy, scripted events, a fall in lockstep, and
chat asking the LLM again at once with the event observed.

The end-to-end cases run a real lockstep board; the fall is a scripted push on the emulated board
(``--push S:FX,FY,FZ[:DUR]``): 20 N sideways and 15 N up for 0.25 s tip CoCo over."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from host.cli import main as cli_main
from host.run.events import (DEFAULT_ACTIONS, EventFileError, EventMonitor, EventPolicy, parse_event_file,
                             parse_events_table)
from support.fake_llm import FakeLLM, Handler, fake_llm, replay, stream_body  # noqa: F401  (fixture)

PUSH = "1.0:0,20,15:0.25"  # board second 1.0: 20 N sideways and 15 N up for 0.25 s


# -- the events file and the policy table ----------------------------------------------------------------
@pytest.mark.parametrize(("text", "says"), [
    ("at x: hi\n", "'x' is not a number of seconds"),
    ("at -1: hi\n", "finite number of seconds >= 0"),
    ("at nan: hi\n", "finite number of seconds >= 0"),
    ("hello\n", "expected 'at SECONDS: text'"),
    ("at 1:   \n", "has no text"),
    ("# only a comment\n\n", "no events"),
])
def test_bad_event_files_are_refused_with_file_and_line(tmp_path: Path, text: str, says: str) -> None:
    f = tmp_path / "ev.txt"
    f.write_text(text, encoding="utf-8")
    with pytest.raises(EventFileError, match=says) as e:
        parse_event_file(f)
    assert str(f) in str(e.value)
    if "no events" not in says:
        assert f"{f}:1:" in str(e.value)


def test_event_file_lines_sorted_by_time(tmp_path: Path) -> None:
    f = tmp_path / "ev.txt"
    f.write_text("# a comment\nat 2.5: the doorbell rang\n\nat 0.5: a child waves\n", encoding="utf-8")
    assert [(e.at_s, e.text) for e in parse_event_file(f)] == [(0.5, "a child waves"), (2.5, "the doorbell rang")]


@pytest.mark.parametrize(("table", "says"), [({"events": {"falls": "note"}}, "no event kind"),
                                             ({"events": {"fall": "panic"}}, "choose one of"),
                                             ({"events": "interrupt"}, "must be a table")])
def test_bad_events_tables_are_refused(table: dict[str, Any], says: str) -> None:
    with pytest.raises(EventFileError, match=says):
        parse_events_table(table)


def test_events_table_overrides_the_defaults() -> None:
    actions = parse_events_table({"events": {"stall": "interrupt", "scripted": "ignore"}})
    assert actions == {**DEFAULT_ACTIONS, "stall": "interrupt", "scripted": "ignore"}


# -- detection ------------------------------------------------------------------------------------------
def _quat_tilt(deg: float) -> tuple[float, float, float, float]:
    h = math.radians(deg) / 2
    return (math.cos(h), math.sin(h), 0.0, 0.0)


def test_monitor_reports_tilt_then_one_fall_then_rearms() -> None:
    m = EventMonitor(["a"], floating=True)
    kinds = [[e.kind for e in m.feed(t, [0.0], ((0, 0, 0.09), _quat_tilt(deg)))]
             for t, deg in ((0.0, 5), (0.1, 30), (0.2, 50), (0.3, 80), (0.4, 5), (0.5, 60))]
    assert kinds == [[], ["tilt"], ["fall"], [], [], ["fall"]]


def test_a_fixed_base_never_falls() -> None:
    m = EventMonitor(["a"], floating=False)
    assert m.feed(0.0, [0.0], ((0, 0, 0.0), _quat_tilt(90))) == []


def test_monitor_reports_a_stall_once_per_servo() -> None:
    target = np.array([0.0, 1.0])
    m = EventMonitor(["ok", "blocked"], floating=False, targets=lambda t_us: target, limits=[(-1.0, 1.0)] * 2)
    got = [e for t in np.arange(0.0, 2.0, 0.02) for e in m.feed(float(t), [0.0, 0.4], None, efforts=[0.0, 1.0])]
    assert [(e.kind, e.data["servo"]) for e in got] == [("stall", "blocked")]
    assert got[0].board_time_s >= 0.2 and got[0].data["error_deg"] == pytest.approx(34.4, abs=0.1)


def test_a_moving_target_is_no_stall() -> None:
    m = EventMonitor(["a"], floating=False, targets=lambda t_us: np.array([t_us * 1e-6]))
    assert not [e for t in np.arange(0.0, 3.0, 0.02) for e in m.feed(float(t), [0.0], None)]


def test_monitor_reports_a_loss_burst_and_toppled_objects() -> None:
    m = EventMonitor(["a"], floating=False)
    got = [e.kind for t, lost, top in ((0.0, 0, 0), (0.5, 2, 0), (0.9, 6, 1), (1.0, 12, 1), (3.0, 20, 3))
           for e in m.feed(t, [0.0], None, toppled=top, losses=lost)]
    assert got == ["toppled", "link", "toppled"]  # one link event per quiet period


# -- end to end --------------------------------------------------------------------------------------------
def test_a_fall_interrupts_the_running_turn(tmp_path: Path) -> None:
    out = tmp_path / "run"
    rc = cli_main(["run", "--lockstep", "--no-live", "--out", str(out), "--push", PUSH,
                   "--xml", '<head_act action="nod" duration="4"/><wait><move_strides times="2"/></wait>'])
    assert rc == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["outcome"] == "interrupted" and s["fell"]
    assert s["extra"]["interrupted_by"].startswith("fall at board time")
    fall_t = float(s["extra"]["interrupted_by"].split("board time ")[1].split(" s")[0])
    assert 1.0 < fall_t < 2.0
    calls = json.loads((out / "timeline.json").read_text())["calls"]
    nod = next(c for c in calls if c["function"] == "head_act")
    assert nod["outcome"] == "interrupted" and nod["end"] <= fall_t + 0.2  # stopped right after the fall
    assert next(c for c in calls if c["function"] == "move_strides")["start"] is None  # never started


def test_a_scripted_event_interrupts_or_is_noted_as_the_policy_says(tmp_path: Path) -> None:
    events = tmp_path / "events.txt"
    events.write_text("at 1.0: the doorbell rang\n", encoding="utf-8")
    out = tmp_path / "interrupt"
    assert cli_main(["run", "--lockstep", "--no-live", "--out", str(out), "--events", str(events),
                     "--xml", '<head_act action="nod" duration="4"/>']) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["outcome"] == "interrupted" and "the doorbell rang" in s["extra"]["interrupted_by"]
    nod = json.loads((out / "timeline.json").read_text())["calls"][0]
    assert 0.9 < nod["end"] < 1.4  # cut near board second 1.0 of the session, not after 4 s

    policy = tmp_path / "policy.toml"
    policy.write_text('[events]\nscripted = "note"\n', encoding="utf-8")
    out = tmp_path / "note"
    assert cli_main(["run", "--lockstep", "--no-live", "--out", str(out), "--events", str(events),
                     "--policy", str(policy), "--xml", '<head_act action="nod" duration="3"/>']) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["outcome"] == "done" and "interrupted_by" not in s["extra"]
    assert any("event: scripted at board time" in o and "doorbell" in o for o in s["extra"]["observations"])


@pytest.mark.parametrize(("argv", "says"), [
    (["--events", "missing.txt"], "cannot read it"),
    (["--push", "1:0,25"], "three finite components"),
    (["--push", "soon:0,0,0"], "expected S:FX,FY,FZ"),
    (["--link", "/dev/pts/999", "--push", PUSH], "--push acts in the emulated board"),
])
def test_bad_event_arguments_exit_2_before_anything_starts(tmp_path: Path, argv: list[str], says: str,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    try:
        rc = cli_main(["run", "--lockstep", "--no-live", "--out", str(tmp_path / "r"), "--xml", "<head_act/>", *argv])
    except SystemExit as e:  # argparse refuses a bad --push value itself
        rc = int(e.code or 0)
    err = capsys.readouterr().err
    assert rc == 2 and says in err and "Traceback" not in err
    assert not (tmp_path / "r").exists()


def test_chat_asks_again_at_once_with_the_fall_observed(fake_llm: FakeLLM, tmp_path: Path) -> None:  # noqa: F811
    """The next LLM request carries the event: a fall interrupts step 1, step 2 is requested at once."""
    replies = [['<head_act action="nod" duration="4"/>Nodding for a while.'], ["Oh no, I fell over."]]

    def respond(h: Handler, fake: FakeLLM) -> None:
        replay(stream_body(replies[min(len(fake.requests), len(replies)) - 1]))(h, fake)

    fake_llm.responder = respond
    (tmp_path / "turns.txt").write_text("Nod for a while.\n", encoding="utf-8")
    out = tmp_path / "chat"
    rc = cli_main(["chat", "--llm", "openai:test-model", "--base-url", fake_llm.base_url, "--api-key", "k",
                   "--turns", str(tmp_path / "turns.txt"), "--lockstep", "--no-live", "--push", PUSH,
                   "--out", str(out)])
    assert rc == 0
    reqs = [r["json"]["messages"] for r in fake_llm.requests]
    assert len(reqs) == 2  # one user turn, asked again after the event
    last = reqs[1][-1]
    text = last["content"] if isinstance(last["content"], str) else last["content"][0]["text"]
    assert last["role"] == "user" and "events:" in text and "- fall at board time" in text
    assert "interrupted: by the event above (fall)" in text
    turn = json.loads((out / "transcript.json").read_text())["turns"][0]
    assert [s["interrupted"] for s in turn["steps"]] == [True, False] and not turn["interrupted"]
