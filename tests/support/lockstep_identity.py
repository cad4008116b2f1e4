"""Is a lockstep run a function of its input? Run ``ghostshell run --lockstep`` quiet and disturbed, and
compare what the board received and did.

``board_record(run_dir) -> Record`` reads the board's frame log (``board_frames.jsonl``, written by the
board process: every frame in and out, in order) into what must not depend on the host's timing:

* ``rx``: every message the board received, in order: ``"seq TYPE fields"`` (a HELLO's and a TIME_SYNC
  request's host wall-clock stamp left out: they say when, not what);
* ``tx``: every message the board sent (reports, ACKs, NACKs), in order, as its raw bytes (a TIME_SYNC
  reply, which echoes the host's wall clock, left out). A lockstep board handles a received message only
  when it cannot tick, so each of its reports (board time, positions, ``buffer_fill``,
  ``last_applied_seq``, counters, SIM_STATE) says what it had applied and when;
* ``final``: the last TELEMETRY and the last SIM_STATE, raw.

The frame log's own ``t`` (the board time a message was *received*, not handled) is left out: it depends on
when the bytes came, and the board's behaviour does not (``firmware_sim.server.BoardServer._serve_lockstep``).

``Disturbance`` (a context manager around a running host process) adds a CPU hog per core and SIGSTOPs
the host process for ``stop_s`` every ``period_s``; with ``stalls`` the host's control path stalls at
random (``GHOSTSHELL_STALLS``, :mod:`host.motion.stalls`). ``run_lockstep(...) -> Run`` runs one program
and returns the board's :class:`Record`, the process and the number of SIGSTOPs.
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType

from protocol.framing import Frame, FrameDecoder

ROOT = Path(__file__).resolve().parents[2]
GHOSTSHELL = ROOT / ".venv" / "bin" / "ghostshell"

__all__ = ["Disturbance", "Record", "Run", "board_record", "compare", "first_difference", "run_lockstep"]

#: the handshake: how often a HELLO or a TIME_SYNC is tried depends on wall-clock timeouts (a host stopped
#: while the CAPS came retries it); everything after it must not
_HANDSHAKE_RX = ("HELLO", "TIME_SYNC_REQUEST")
_HANDSHAKE_TX = ("CAPS", "TIME_SYNC_REPLY")
#: payload fields that carry a host sequence number
_HOST_SEQ_FIELDS = ("last_applied_seq", "ack_seq")
#: payload fields that carry the host's wall clock (when, not what): zeroed after the handshake
_WALL_FIELDS = ("t1_host_us", "host_time_us", "sender_time_us")


@dataclass
class Record:
    """What the board received (``rx``), sent (``tx``) and ended with (``final``), timing left out.

    ``tx`` ends with the last report at ``end_us``; ``cut(end_us)`` shortens it to an earlier end."""

    rx: list[str] = field(default_factory=list)
    tx: list[tuple[int, str]] = field(default_factory=list)  # (board time us of the report it follows, message)
    truncated: bool = False  # the log ended in a line cut short (the board was stopped mid-write)

    @property
    def end_us(self) -> int:
        return self.tx[-1][0] if self.tx else 0

    def cut(self, end_us: int) -> Record:
        """This record with the board's messages up to and including the reports at ``end_us``."""
        return Record(list(self.rx), [(t, m) for t, m in self.tx if t <= end_us], self.truncated)

    @property
    def final(self) -> list[str]:
        """The last TELEMETRY and SIM_STATE."""
        last: dict[str, str] = {}
        for _, m in self.tx:
            kind = _kind(m)
            if kind in ("Telemetry", "SimState"):
                last[kind] = m
        return [last[k] for k in sorted(last)]

    def counts(self) -> dict[str, int]:
        """Messages received by type (for messages in a test's failure)."""
        out: dict[str, int] = {}
        for line in self.rx:
            kind = _kind(line)
            out[kind] = out.get(kind, 0) + 1
        return out


def _kind(line: str) -> str:
    """The message class of a record line ``"seq Kind(...)"``."""
    return line.split(" ", 1)[1].split("(", 1)[0]


def _decode(raw: str) -> Frame | None:
    items = FrameDecoder().feed(bytes.fromhex(raw))
    return items[0] if items and isinstance(items[0], Frame) else None


def _shift(msg: object, offset: int) -> object:
    """``msg`` with its host sequence numbers made relative to ``offset`` (0 stays 0: nothing applied yet)."""
    changes: dict[str, int] = {k: (getattr(msg, k) - offset) & 0xFFFF for k in _HOST_SEQ_FIELDS
                               if hasattr(msg, k) and getattr(msg, k)}
    changes.update({k: 0 for k in _WALL_FIELDS if hasattr(msg, k)})
    return dataclasses.replace(msg, **changes) if changes else msg  # type: ignore[type-var]


def board_record(run_dir: Path) -> Record:
    """The :class:`Record` of the board's frame log in ``run_dir`` (``board_frames.jsonl``): the messages
    after the handshake, each decoded from its raw bytes (full precision) with sequence numbers made
    relative to the first message after the handshake (a retried HELLO shifts them all by one) and the
    host's wall-clock stamps zeroed (a TIME_SYNC or HEARTBEAT sent later still counts as a message)."""
    rec = Record()
    host0: int | None = None
    board0: int | None = None
    now_us = 0
    with open(run_dir / "board_frames.jsonl", encoding="utf-8") as f:
        for line in f:
            try:
                d = json.loads(line)
            except json.JSONDecodeError:  # a line cut short when the board was stopped: the log ends here
                rec.truncated = True
                break
            kind = d.get("type", "?")
            frame = _decode(d.get("raw", ""))
            if frame is None:
                continue
            if d.get("dir") == "rx":
                if kind in _HANDSHAKE_RX and host0 is None:  # later ones count: sent mid-run
                    continue
                host0 = frame.seq if host0 is None else host0
                rec.rx.append(f"{(frame.seq - host0) & 0xFFFF} {_shift(frame.msg, host0)!r}")
            elif d.get("dir") == "tx" and not (kind in _HANDSHAKE_TX and board0 is None):
                board0 = frame.seq if board0 is None else board0
                msg = _shift(frame.msg, host0 or 0)
                now_us = getattr(msg, "board_time_us", now_us)
                rec.tx.append((now_us, f"{(frame.seq - board0) & 0xFFFF} {msg!r}"))
    return rec


def compare(a: Record, b: Record) -> str:
    """"identical" when ``a`` and ``b`` agree up to the earlier of their ends, else where they part.

    The board's last reports depend on when it was stopped (the host closes the link and stops it once
    the run ended; a lockstep board runs on to the end of the frames it was sent meanwhile), so the
    board's messages are compared up to the earlier end, and the received ones up to the shorter
    stream (the bytes in flight at the stop are not read)."""
    end = min(a.end_us, b.end_us)
    a, b = a.cut(end), b.cut(end)
    n = min(len(a.rx), len(b.rx))
    for what, x, y in (("rx", a.rx[:n], b.rx[:n]), ("tx", [m for _, m in a.tx], [m for _, m in b.tx]),
                       ("final", a.final, b.final)):
        diff = first_difference(x, y)
        if diff != "identical":
            return f"{what} {diff}"
    return "identical"


def first_difference(a: list[str], b: list[str]) -> str:
    """Where two record lists part, as one line (or "identical")."""
    for i, (x, y) in enumerate(zip(a, b)):
        if x != y:
            return f"item {i}: {x[:160]!r} != {y[:160]!r}"
    if len(a) != len(b):
        return f"lengths {len(a)} != {len(b)}"
    return "identical"


class Disturbance:
    """A CPU hog per core, and SIGSTOP/SIGCONT of ``pid`` (``stop_s`` stopped every ``period_s``), while
    the ``with`` block runs. Wall-clock pauses are the disturbance here, not synchronisation."""

    def __init__(self, pid: int, *, hogs: int | None = None, stop_s: float = 0.25, period_s: float = 0.5,
                 start_when: Callable[[], bool] | None = None) -> None:
        self.pid = pid
        self.start_when = start_when  # polled every 20 ms before the disturbance starts (None: at once)
        self.hogs = (os.cpu_count() or 1) if hogs is None else hogs
        self.stop_s, self.period_s = stop_s, period_s
        self._done = threading.Event()
        self._procs: list[subprocess.Popen[bytes]] = []
        self._thread = threading.Thread(target=self._toggle, daemon=True)
        self.stops = 0

    def _signal(self, sig: signal.Signals) -> bool:
        """Send ``sig`` to the process through its pidfd (never to a recycled pid); False once it is gone."""
        try:
            signal.pidfd_send_signal(self._pidfd, sig)
        except ProcessLookupError:
            return False
        return True

    def _toggle(self) -> None:
        while self.start_when is not None and not self.start_when():
            if self._done.wait(0.02):
                return
        for _ in range(self.hogs):  # a busy loop each, until __exit__ kills it
            self._procs.append(subprocess.Popen([sys.executable, "-c", "while True: pass"]))
        while not self._done.wait(self.period_s - self.stop_s):
            if not self._signal(signal.SIGSTOP):
                return
            self.stops += 1
            self._done.wait(self.stop_s)
            if not self._signal(signal.SIGCONT):
                return

    def __enter__(self) -> Disturbance:
        self._pidfd = os.pidfd_open(self.pid)  # before the process can be reaped: its pid is not reused
        self._thread.start()
        return self

    def __exit__(self, et: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self._done.set()
        self._thread.join()
        self._signal(signal.SIGCONT)
        os.close(self._pidfd)
        for p in self._procs:
            p.kill()
            p.wait()


@dataclass
class Run:
    """One ``ghostshell run --lockstep``: the board's :class:`Record`, the finished process and how often
    its host was SIGSTOPped (0 for a quiet run)."""

    record: Record
    proc: subprocess.CompletedProcess[str]
    stops: int = 0


def run_lockstep(out: Path, xml: str, robot_args: list[str], *, disturb: bool = False,
                 stalls: str | None = None, timeout_s: float = 300.0) -> Run:
    """Run ``ghostshell run --lockstep --no-live --no-plots`` of ``xml`` into ``out``: quiet, or with a
    :class:`Disturbance` from the first servo frames on and ``GHOSTSHELL_STALLS=stalls``."""
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    env.pop("GHOSTSHELL_STALLS", None)
    if stalls:
        env["GHOSTSHELL_STALLS"] = stalls
    cmd = [str(GHOSTSHELL), "run", *robot_args, "--xml", xml, "--lockstep", "--no-live", "--no-plots", "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    log = out / "board_frames.jsonl"
    stops = 0
    if disturb:  # from the first servo frames on: the handshake's retries are wall-clock business anyway
        with Disturbance(proc.pid, start_when=lambda: log.exists() and log.stat().st_size > 4096) as dist:
            stdout, stderr = proc.communicate(timeout=timeout_s)
        stops = dist.stops
    else:
        stdout, stderr = proc.communicate(timeout=timeout_s)
    done = subprocess.CompletedProcess(cmd, proc.returncode, stdout, stderr)
    return Run(board_record(out) if log.exists() else Record(), done, stops)
