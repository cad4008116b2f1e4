"""Ctrl-C is an interruption (issue 16, item 1): real signals to real ``ghostshell`` processes.

A terminal's Ctrl-C signals the foreground process group: :meth:`support.cliproc.Cli.ctrl_c` does
exactly that (the command leads its own group). The emulated board runs in a group of its own, so
it never sees the Ctrl-C; the host interrupts the turn through the lifecycle tree, moves the robot
to its rest pose, writes everything, prints one line and exits 130. Each test waits for the run to
be under way by watching the host's frame log (servo frames that walk the robot away from its start
pose), never by a guessed sleep.
"""

from __future__ import annotations

import json
import math
import signal
from pathlib import Path

import pytest

from support.cliproc import Cli, processes_mentioning, servo_frames_moving_s, start, wait_until

pytestmark = pytest.mark.timeout(240)

#: board seconds of servo frames sent before the signal that move the robot away from its start pose: task 9
#: walks, so its turn is under way
UNDER_WAY_S = 1.5


def _start_pose() -> tuple[float, ...]:
    from robots.registry import load_robot

    robot = load_robot()
    return robot.pose(robot.start_pose)


def _stand_deg() -> list[float]:
    from robots.registry import load_robot

    robot = load_robot()
    return [math.degrees(v) for v in robot.pose(robot.rest_pose)]


def _last_positions_deg(run: Path) -> list[float]:
    """The board's last reported joint angles (its own frame log: serial JSON Lines or CAN candump)."""
    jsonl = run / "board_frames.jsonl"
    if jsonl.exists():
        tel = [json.loads(line) for line in jsonl.read_text().splitlines() if '"TELEMETRY"' in line]
        return [math.degrees(v) for v in tel[-1]["fields"]["positions"]]
    from host.link.canlog import iter_can_log
    from protocol.can import CanItem
    from protocol.messages import Telemetry

    last = None
    for e in iter_can_log(run / "board_frames.log"):
        for it in e.items:
            if isinstance(it, CanItem) and isinstance(it.msg, Telemetry):
                last = it.msg
    assert last is not None
    return [math.degrees(v) for v in last.positions]


def _run(tmp_path: Path, *extra: str) -> tuple[Cli, Path]:
    out = tmp_path / "run"
    cli = start(["run", "--task", "9", "--no-live", "--out", str(out), *extra], tmp_path / "logs")
    wait_until(lambda: servo_frames_moving_s(out, _start_pose()) > UNDER_WAY_S, "the run is under way", proc=cli)
    return cli, out


def _check_interrupted(cli: Cli, out: Path, rc: int, by: str = "SIGINT") -> dict:
    err = cli.stderr.strip().splitlines()
    assert rc == 130, cli.stderr[-3000:]
    assert len(err) == 1 and f"interrupted by {by}" in err[0] and "rest pose 'stand'" in err[0], err
    assert f"artefacts in {out}/" in err[0]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"] == "interrupted", summary
    assert summary["extra"]["stopped"] == {"by": by, "kind": "signal", "message": summary["extra"]["stopped"]["message"],
                                           "rest_pose": "stand"}
    assert "link_error" not in summary["extra"]  # the board never saw the Ctrl-C: the link was never lost
    calls = json.loads((out / "timeline.json").read_text())["calls"]
    assert any(c["outcome"] == "interrupted" for c in calls) and any(c["start"] is not None for c in calls), calls
    for name in ("timeline.png", "joints.png"):
        assert (out / name).exists(), name
    # the robot stands at its rest pose: the board's own last report, every servo within 3 deg
    errors = [abs(a - b) for a, b in zip(_last_positions_deg(out), _stand_deg())]
    assert max(errors) < 3.0, errors
    assert processes_mentioning(str(out)) == []  # the board process is gone too
    return summary


def test_ctrl_c_lockstep_serial(tmp_path: Path) -> None:
    cli, out = _run(tmp_path, "--lockstep")
    cli.ctrl_c()
    _check_interrupted(cli, out, cli.wait())
    assert "link" not in (out / "board.stderr").read_text().lower().replace("board: ", "")


@pytest.mark.realtime
def test_ctrl_c_realtime_serial(tmp_path: Path) -> None:
    cli, out = _run(tmp_path, "--realtime")
    cli.ctrl_c()
    _check_interrupted(cli, out, cli.wait())


@pytest.mark.slow
def test_ctrl_c_lockstep_can(tmp_path: Path) -> None:
    cli, out = _run(tmp_path, "--lockstep", "--link", "can:slcan:pty")
    cli.ctrl_c()
    _check_interrupted(cli, out, cli.wait())


@pytest.mark.realtime
@pytest.mark.slow
def test_ctrl_c_realtime_can(tmp_path: Path) -> None:
    cli, out = _run(tmp_path, "--realtime", "--link", "can:slcan:pty")
    cli.ctrl_c()
    _check_interrupted(cli, out, cli.wait())


def test_sigterm_to_the_host_alone_is_the_same(tmp_path: Path) -> None:
    cli, out = _run(tmp_path, "--lockstep")
    cli.signal(signal.SIGTERM)  # `kill PID`: the host only, not its group
    _check_interrupted(cli, out, cli.wait(), by="SIGTERM")


def _delivered(pid: int, sig: int) -> bool:
    """True when ``sig`` is no longer pending for ``pid`` (the kernel handed it to the process)."""
    status = Path(f"/proc/{pid}/status").read_text()
    pending = 0
    for line in status.splitlines():
        if line.startswith(("SigPnd:", "ShdPnd:")):
            pending |= int(line.split()[1], 16)
    return not pending & (1 << (sig - 1))


@pytest.mark.realtime
def test_second_ctrl_c_stops_at_once_and_leaves_a_readable_summary(tmp_path: Path) -> None:
    cli, out = _run(tmp_path, "--realtime")
    cli.ctrl_c()
    # two SIGINTs sent together merge into one pending signal: the second goes once the first was delivered
    wait_until(lambda: _delivered(cli.proc.pid, signal.SIGINT), "the first SIGINT is delivered", timeout=10)
    cli.ctrl_c()
    rc = cli.wait()
    err = cli.stderr.strip().splitlines()
    assert rc == 130 and len(err) == 1 and "stopped at once" in err[0], cli.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"] == "interrupted"
    assert summary["extra"]["stopped"]["by"] == "SIGINT" and summary["extra"]["stopped"]["forced_by"] == "SIGINT"
    calls = json.loads((out / "timeline.json").read_text())["calls"]
    assert calls and all(c["outcome"] != "pending" for c in calls), calls
    assert not (out / "timeline.png").exists()  # at once: no plots
    assert processes_mentioning(str(out)) == []


def test_ctrl_c_while_the_demo_renders_leaves_no_video(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    cli = start(["demo", "--lockstep", "--no-live", "--out", str(out)], tmp_path / "logs")
    # the run is complete (its summary written) and run.mp4 is being rendered
    wait_until(lambda: (out / "summary.json").exists(), "the demo's run has finished", timeout=120, proc=cli)
    wait_until(lambda: (out / "run.partial.mp4").exists(), "the render has begun", timeout=60, proc=cli)
    cli.ctrl_c()
    rc = cli.wait()
    err = cli.stderr.strip().splitlines()
    assert rc == 130 and len(err) == 1 and "interrupted by SIGINT" in err[0], cli.stderr[-3000:]
    assert not (out / "run.mp4").exists() and not (out / "run.partial.mp4").exists()
    assert json.loads((out / "summary.json").read_text())["outcome"] == "done"  # the run itself had finished
    assert processes_mentioning(str(out)) == []


def test_ctrl_c_ends_a_chat_at_rest_with_its_transcript(tmp_path: Path) -> None:
    from robots.registry import load_robot
    from robots.tasks import get_task

    robot = load_robot()
    square = get_task(robot.tasks, 9).ground_truth
    replies = tmp_path / "replies.txt"
    replies.write_text(f"{square}\n---\n{square}\n", encoding="utf-8")
    out = tmp_path / "chat"
    cli = start(["chat", "--replies", str(replies), "--lockstep", "--no-live", "--out", str(out)], tmp_path / "logs")
    wait_until(lambda: servo_frames_moving_s(out, _start_pose()) > UNDER_WAY_S, "the first turn is under way", proc=cli)
    cli.ctrl_c()
    rc = cli.wait()
    err = cli.stderr.strip().splitlines()
    assert rc == 130 and len(err) == 1, cli.stderr[-3000:]
    assert "interrupted by SIGINT" in err[0] and "after 1 turn" in err[0] and "rest pose 'stand'" in err[0], err
    doc = json.loads((out / "transcript.json").read_text())
    assert len(doc["turns"]) == 1 and doc["turns"][0]["interrupted"], doc["turns"]  # the second reply never ran
    step = json.loads((out / "turn_01" / "step_1" / "summary.json").read_text())
    assert step["outcome"] == "interrupted" and step["extra"]["stopped"]["by"] == "SIGINT"
    errors = [abs(a - b) for a, b in zip(_last_positions_deg(out), _stand_deg())]
    assert max(errors) < 3.0, errors
    assert processes_mentioning(str(out)) == []


def test_ctrl_c_stops_the_mcp_server_and_its_board(tmp_path: Path) -> None:
    out = tmp_path / "mcp"
    # stdin stays open (a client that is still connected): the server must not wait for it to close
    cli = start(["mcp", "--lockstep", "--out", str(out)], tmp_path / "logs", stdin_pipe=True)
    assert cli.proc.stdin is not None
    init = {"jsonrpc": "2.0", "id": 1, "method": "initialize",
            "params": {"protocolVersion": "2025-06-18", "capabilities": {}, "clientInfo": {"name": "t", "version": "1"}}}
    cli.proc.stdin.write((json.dumps(init) + "\n").encode())
    cli.proc.stdin.flush()
    # the server answers once its robot session (board, link, start pose) is up
    wait_until(lambda: '"id":1' in cli.stdout.replace(" ", ""), "the server answers initialize", proc=cli)
    cli.ctrl_c()
    rc = cli.wait()
    last = cli.stderr.strip().splitlines()[-1]
    assert rc == 130 and "interrupted by SIGINT" in last and "the board with it" in last, cli.stderr[-3000:]
    assert "Traceback" not in cli.stderr
    errors = [abs(a - b) for a, b in zip(_last_positions_deg(out), _stand_deg())]
    assert max(errors) < 3.0, errors
    assert processes_mentioning(str(out)) == []


def test_ctrl_c_stops_a_tour_and_its_board(tmp_path: Path) -> None:
    out = tmp_path / "tour"
    cli = start(["tour", "--lockstep", "--duration", "5", "--out", str(out)], tmp_path / "logs")
    wait_until(lambda: "reached" in cli.stdout, "the tour reached its first pose", proc=cli)
    cli.ctrl_c()
    rc = cli.wait()
    err = cli.stderr.strip().splitlines()
    assert rc == 130 and err == ["ghostshell tour: interrupted by SIGINT (Ctrl-C)"], cli.stderr[-3000:]
    assert processes_mentioning(str(out)) == []


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_one_signal_while_starting_is_reported_as_one(tmp_path: Path, sig: signal.Signals) -> None:
    """Reported: ``setsid ghostshell run ... & sleep 1; kill -INT $!`` said "then SIGINT again"."""
    from support.cliproc import start_while_starting

    out = tmp_path / "run"
    cli = start_while_starting(["run", "--task", "26", "--no-live", "--out", str(out)], tmp_path / "logs")
    cli.signal(sig)  # one signal, to the host alone, while its handshake waits for the board
    rc = cli.wait()
    err = cli.stderr.strip().splitlines()
    assert rc == 130 and len(err) == 1, cli.stderr[-3000:]
    how = "(Ctrl-C)" if sig == signal.SIGINT else ""
    assert f"interrupted by {sig.name}{' ' + how if how else ''} while starting: stopped at once" in err[0], err
    assert "again" not in err[0], err
    stopped = json.loads((out / "summary.json").read_text())["extra"]["stopped"]
    assert stopped["by"] == stopped["forced_by"] == sig.name and stopped["while_starting"] is True, stopped
