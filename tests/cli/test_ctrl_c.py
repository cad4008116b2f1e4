"""Ctrl-C is an interruption (issue 16, item 1): real signals to real ``ghostshell`` processes.

A terminal's Ctrl-C signals the foreground process group: :meth:`support.cliproc.Cli.ctrl_c` does
exactly that (the command leads its own group). The emulated board runs in a group of its own, so
it never sees the Ctrl-C; the host interrupts the turn through the lifecycle tree, moves the robot
to its rest pose, writes everything, prints one line and exits 130. Each test waits for the run to
be under way by watching the host's frame log (servo frames that walk the robot away from its start
pose), never by a guessed sleep.

A lockstep run goes as fast as the CPU lets it, so a test that waits for it to be under way may see
it only after it ended (CI, 2026-12-04: task 9 over SLCAN ended with status 0 before the Ctrl-C).
The lockstep runs here therefore take their reply from a local OpenAI-compatible server
(:mod:`support.fake_llm`) that sends the program and then holds the stream open until the test is
done: a lockstep board stands still while the host waits for the LLM's next chunk
(:meth:`host.motion.streamer.FrameStreamer.hold`), so the turn cannot end before the signal, whatever
the machine's load. The realtime runs keep the scripted LLM: they are marked ``realtime`` (their
poller is not starved) and last 26 wall seconds.
"""

from __future__ import annotations

import json
import math
import signal
import threading
from pathlib import Path

import pytest

from support.cliproc import Cli, processes_mentioning, servo_frames_moving_s, start, wait_until
from support.fake_llm import DONE, FakeLLM, Handler, chunk, fake_llm, sse  # noqa: F401  (fake_llm: a fixture)

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
    """``ghostshell run --task 9`` (scripted, realtime), once its walk is under way."""
    out = tmp_path / "run"
    cli = start(["run", "--task", "9", "--no-live", "--out", str(out), *extra], tmp_path / "logs")
    wait_until(lambda: servo_frames_moving_s(out, _start_pose()) > UNDER_WAY_S, "the run is under way", proc=cli)
    return cli, out


def _square() -> str:
    from robots.registry import load_robot
    from robots.tasks import get_task

    return get_task(load_robot().tasks, 9).ground_truth


class _HeldReply:
    """Every request to ``fake`` is answered with ``program`` as one streamed chunk, once the test
    lets it go, then by one-space chunks, each only when the test asks for it (:meth:`walk_under_way`),
    and then the stream is held open until the test's end (the fixture opens the gate) or the client
    hangs up.

    A lockstep board stands still while the host waits for the LLM's next chunk and runs one
    lookahead further (60 ms) after each, so the test itself paces the walk: a poller that gets
    little CPU sees the walk slowly, never after the turn ended."""

    def __init__(self, fake: FakeLLM, program: str) -> None:
        self.asked, self._go, self._more = threading.Event(), threading.Event(), threading.Semaphore(0)
        self._enough = False

        def respond(h: Handler, f: FakeLLM) -> None:
            h.start_sse()
            h.write_piece(sse(chunk("", role="assistant")))
            self.asked.set()
            if not self._go.wait(timeout=300) or not h.write_piece(sse(chunk(program))):
                return
            while self._more.acquire(timeout=300) and not self._enough:
                if not h.write_piece(sse(chunk(" "))):
                    return
            f.wait_gate(timeout=300)
            if h.write_piece(sse(chunk(None, finish="stop"))) and h.write_piece(DONE):
                h.end_chunked()

        fake.responder = respond

    def walk_under_way(self, cli: Cli, out: Path) -> None:
        """Wait for the request (the turn has begun: the move to the start pose is in the frame log),
        then let the program go and one more chunk per poll until servo frames spanning
        ``UNDER_WAY_S`` board seconds moved the robot away from its start pose beyond those sent
        before the turn; from then on the reply is held."""
        def under_way() -> bool:
            if servo_frames_moving_s(out, _start_pose()) > before + UNDER_WAY_S:
                self._enough = True
                self._more.release()
                return True
            self._more.release()
            return False

        try:
            wait_until(self.asked.is_set, "the host asks the LLM", proc=cli)
            before = servo_frames_moving_s(out, _start_pose())
            self._go.set()
            wait_until(under_way, "the walk is under way", proc=cli)
        except BaseException:  # the test fails here: end the stream and the command now, not in 5 minutes
            self._enough = True
            self._go.set()
            self._more.release()
            cli.kill()
            raise


def _llm_args(fake: FakeLLM) -> list[str]:
    return ["--llm", "openai:test-model", "--base-url", fake.base_url, "--api-key", "test-key"]


def _run_held(tmp_path: Path, fake: FakeLLM, *extra: str) -> tuple[Cli, Path]:
    """``ghostshell run --lockstep`` of task 9's program from a reply held open (:class:`_HeldReply`),
    once the walk is under way; the turn cannot end before the test's signal."""
    held = _HeldReply(fake, _square())
    out = tmp_path / "run"
    cli = start(["run", "--prompt", "Walk in a square with 20cm sides", *_llm_args(fake), "--lockstep", "--no-live",
                 "--out", str(out), *extra], tmp_path / "logs")
    held.walk_under_way(cli, out)
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


def test_ctrl_c_lockstep_serial(tmp_path: Path, fake_llm: FakeLLM) -> None:
    cli, out = _run_held(tmp_path, fake_llm)
    cli.ctrl_c()
    _check_interrupted(cli, out, cli.wait())
    assert "link" not in (out / "board.stderr").read_text().lower().replace("board: ", "")


@pytest.mark.realtime
def test_ctrl_c_realtime_serial(tmp_path: Path) -> None:
    cli, out = _run(tmp_path, "--realtime")
    cli.ctrl_c()
    _check_interrupted(cli, out, cli.wait())


@pytest.mark.slow
def test_ctrl_c_lockstep_can(tmp_path: Path, fake_llm: FakeLLM) -> None:
    cli, out = _run_held(tmp_path, fake_llm, "--link", "can:slcan:pty")
    cli.ctrl_c()
    _check_interrupted(cli, out, cli.wait())


@pytest.mark.realtime
@pytest.mark.slow
def test_ctrl_c_realtime_can(tmp_path: Path) -> None:
    cli, out = _run(tmp_path, "--realtime", "--link", "can:slcan:pty")
    cli.ctrl_c()
    _check_interrupted(cli, out, cli.wait())


def test_sigterm_to_the_host_alone_is_the_same(tmp_path: Path, fake_llm: FakeLLM) -> None:
    cli, out = _run_held(tmp_path, fake_llm)
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


def test_ctrl_c_ends_a_chat_at_rest_with_its_transcript(tmp_path: Path, fake_llm: FakeLLM) -> None:
    held = _HeldReply(fake_llm, _square())  # the first turn's reply is held open: the second turn never comes
    turns = tmp_path / "turns.txt"
    turns.write_text("Walk in a square with 20cm sides\n---\nAnd again\n", encoding="utf-8")
    out = tmp_path / "chat"
    cli = start(["chat", "--turns", str(turns), *_llm_args(fake_llm), "--lockstep", "--no-live", "--out", str(out)],
                tmp_path / "logs")
    held.walk_under_way(cli, out)
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


@pytest.mark.realtime
def test_ctrl_c_stops_a_tour_and_its_board(tmp_path: Path) -> None:
    # realtime: a lockstep tour went through all six poses in under a second after the first one
    out = tmp_path / "tour"
    cli = start(["tour", "--realtime", "--duration", "2", "--out", str(out)], tmp_path / "logs")
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
