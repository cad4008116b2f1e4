"""``ghostshell`` as a real process a terminal would run: its own process group, real signals.

A terminal's Ctrl-C sends SIGINT to the foreground process group; :func:`start` puts the command in
a new session (so it leads its own group, as a shell job does) and :meth:`Cli.ctrl_c` signals that
whole group with ``os.killpg``, exactly what the terminal does. :func:`wait_until` polls an
observable condition (a frame in a log, a file) with a deadline: synchronisation on an event the
run shows, not a guessed sleep. :func:`processes_mentioning` finds processes whose command line
names a path (a run folder): the emulated board gets ``--log RUN/board_frames.*``, so a board left
behind by a run is found by its folder.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

__all__ = ["Cli", "last_telemetry", "processes_mentioning", "servo_frames_moving_s", "start", "start_while_starting",
           "wait_until"]


class Cli:
    """A running ``python -m host ARGS`` (stdout/stderr to files in ``logs``)."""

    def __init__(self, args: Sequence[str], logs: Path, env: dict[str, str] | None = None,
                 stdin_pipe: bool = False) -> None:
        logs.mkdir(parents=True, exist_ok=True)
        self.out_path, self.err_path = logs / "cli.stdout", logs / "cli.stderr"
        self._out, self._err = open(self.out_path, "wb"), open(self.err_path, "wb")
        stdin = subprocess.PIPE if stdin_pipe else subprocess.DEVNULL  # a pipe stays open (a client, a user)
        self.proc = subprocess.Popen([sys.executable, "-m", "host", *args], stdin=stdin,
                                     stdout=self._out, stderr=self._err, start_new_session=True,
                                     env=env if env is not None else dict(os.environ),
                                     preexec_fn=_as_a_foreground_job)
        #: called once the command has been waited for (e.g. closing a pty it was given)
        self.on_exit: list[Callable[[], None]] = []

    def ctrl_c(self, sig: int = signal.SIGINT) -> None:
        """What a terminal does on Ctrl-C: ``sig`` to the command's whole process group."""
        os.killpg(self.proc.pid, sig)

    def signal(self, sig: int) -> None:
        """``sig`` to the command's process alone (``kill PID``)."""
        self.proc.send_signal(sig)

    def wait(self, timeout: float = 120.0) -> int:
        try:
            return self.proc.wait(timeout)
        finally:
            while self.on_exit:
                self.on_exit.pop()()
            self._out.close()
            self._err.close()
            if self.proc.stdin is not None:
                self.proc.stdin.close()

    @property
    def stdout(self) -> str:
        return self.out_path.read_text(errors="replace")

    @property
    def stderr(self) -> str:
        return self.err_path.read_text(errors="replace")

    def kill(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()
        while self.on_exit:
            self.on_exit.pop()()


def _as_a_foreground_job() -> None:
    """SIGINT and SIGQUIT at their defaults in the command, as for a job a terminal runs in the
    foreground: a shell starts background jobs (``pytest ... &``) with both ignored, the children
    inherit that, and Python then installs no KeyboardInterrupt handler, so a Ctrl-C test of a command
    that relies on it (render, tour) saw exit 0 when the suite itself ran in the background."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGQUIT, signal.SIG_DFL)


def start(args: Sequence[str], logs: Path, env: dict[str, str] | None = None, stdin_pipe: bool = False) -> Cli:
    return Cli(args, logs, env, stdin_pipe)


def wait_until(cond: Callable[[], bool], what: str, timeout: float = 60.0, proc: Cli | None = None) -> None:
    """Poll ``cond`` every 20 ms until it holds; AssertionError naming ``what`` after ``timeout`` s (or
    at once when ``proc`` exits first). The polling thread runs at the worker's base nice value
    (:func:`support.realtime_lock.attentive`), so it sees the event soon after it happens even when
    the suite holds ordinary tests at nice 19; keep ``cond`` cheap."""
    from support.realtime_lock import attentive

    deadline = time.monotonic() + timeout
    with attentive():
        while not cond():
            if proc is not None and proc.proc.poll() is not None:
                raise AssertionError(f"the command exited ({proc.proc.returncode}) before {what}:\n"
                                     f"{proc.stderr[-3000:]}")
            if time.monotonic() > deadline:
                raise AssertionError(f"{what}: not within {timeout} s")
            time.sleep(0.02)


def _json_records(path: Path) -> list[dict]:
    records = []
    try:
        lines = path.read_text(errors="replace").splitlines()
    except FileNotFoundError:
        return records
    for line in lines:
        try:
            records.append(json.loads(line))
        except ValueError:  # the line being written
            continue
    return records


def servo_frames_moving_s(run_dir: Path, pose: Sequence[float], tol_rad: float = 0.05) -> float:
    """Board seconds of the SERVO_FRAMEs the host has sent so far (its frame log, ``.jsonl`` serial or
    ``.log`` CAN) that take some servo more than ``tol_rad`` away from both ``pose`` (radians per
    servo: the start pose) and the first frame's target: each such frame counts the time since the
    frame before it. 0 before any.

    "The turn is under way" for a program that moves (a walk). The frames before the turn hold the
    robot where it booted (the first frame's targets), then take it to the start pose in a short
    transition. Neither board time nor the span of the frames says that: a realtime board's clock
    runs from its boot and the host streams hold frames from the connect on, so on a loaded machine
    both pass any mark before the turn begins."""
    frames = sorted(_sent_servo_frames(run_dir, len(pose)), key=lambda f: f[0])
    if not frames:
        return 0.0
    booted = frames[0][1]
    moving = 0.0
    for (t0, _), (t1, targets) in zip(frames, frames[1:]):
        if any(abs(v - pose[i]) > tol_rad and abs(v - booted.get(i, v)) > tol_rad for i, v in targets.items()):
            moving += t1 - t0
    return moving


def _sent_servo_frames(run_dir: Path, n_servos: int) -> list[tuple[float, dict[int, float]]]:
    """(board time s, {servo index: target rad}) of each SERVO_FRAME the host has sent so far."""
    def by_servo(mask: int, targets: Sequence[float]) -> dict[int, float]:  # one target per mask bit (popcount)
        return dict(zip((i for i in range(n_servos) if mask >> i & 1), (float(v) for v in targets)))

    jsonl = run_dir / "host_frames.jsonl"
    if jsonl.exists():
        return [(r["fields"]["apply_at_us"] / 1e6, by_servo(r["fields"]["mask"], r["fields"]["targets"]))
                for r in _json_records(jsonl) if r.get("dir") == "tx" and r.get("type") == "SERVO_FRAME"]
    can_log = run_dir / "host_frames.log"
    if not can_log.exists():
        return []
    from host.link.canlog import iter_can_log
    from protocol.can import CanItem
    from protocol.messages import ServoFrame

    frames: list[tuple[float, dict[int, float]]] = []
    try:
        for e in iter_can_log(can_log):
            for it in e.items:
                if isinstance(it, CanItem) and isinstance(it.msg, ServoFrame) and e.direction == "h>b":
                    frames.append((it.msg.apply_at_us / 1e6, by_servo(it.msg.mask, it.msg.targets)))
    except (OSError, ValueError):  # the line being written
        pass
    return frames


def last_telemetry(run_dir: Path) -> dict:
    """The board's last TELEMETRY record (serial ``board_frames.jsonl``): ``fields`` with positions etc."""
    tel = [r for r in _json_records(run_dir / "board_frames.jsonl") if r.get("type") == "TELEMETRY"]
    assert tel, f"no TELEMETRY in {run_dir / 'board_frames.jsonl'}"
    return tel[-1]["fields"]


def processes_mentioning(text: str) -> list[str]:
    """Command lines of live processes that contain ``text`` (e.g. a run folder a board logs into)."""
    found = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit() or int(proc.name) == os.getpid():
            continue
        try:
            cmd = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            state = (proc / "stat").read_text().split()[2]
        except OSError:
            continue
        if text in cmd and state != "Z":
            found.append(f"{proc.name}: {cmd}")
    return found


def start_while_starting(args: Sequence[str], logs: Path) -> Cli:
    """``python -m host ARGS --link PTY`` where PTY is a pseudo-terminal this process holds and no board
    answers: returned once the host has sent its HELLO (read from the pty), so the command is still
    starting (its handshake waits for CAPS) for as long as the caller likes, with no race to win.
    The pty stays open until the command exits (closing it would look like a lost link)."""
    import select
    import tty

    master, slave = os.openpty()
    tty.setraw(slave)
    cli = start([*args, "--link", os.ttyname(slave)], logs)
    got = bytearray()

    def hello_sent() -> bool:
        while select.select([master], [], [], 0)[0]:
            got.extend(os.read(master, 4096))
        return b"\x00" in got[1:]  # a whole COBS frame (HELLO: the first thing the host sends)

    try:
        wait_until(hello_sent, "the host sends HELLO", proc=cli)
    except BaseException:
        cli.kill()
        raise
    finally:
        os.close(slave)  # the command holds its own descriptor
    cli.on_exit.append(lambda: os.close(master))
    return cli
