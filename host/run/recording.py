"""Feeds a session's :class:`~host.run.mcap_log.RunLog` (run.mcap, and the live view with ``--foxglove``).

A :class:`Recording` listens to the session the way a python-can ``Listener`` listens to a bus, and
touches nothing else:

* board-to-host and host-to-board messages: the client's ``on_received`` (message) and ``on_sent``
  (seq, message) callbacks (TELEMETRY and SIM_STATE go to :meth:`RunLog.on_message`);
* board faults and NACKs: the client's ``on_fault`` / ``on_nack`` callbacks;
* calls and speech: at most every :data:`POLL_S` board seconds, on a report, the shell's live
  timeline (``Shell.last_result``; board-measured start/end from ``RobotRuntime.board_times``: a
  robot call's start line waits for its board-measured start); each call's Event when it ends, and
  at the end of each turn those of the turn's calls that never ended (``on_turn_end``);
* the report that came before the recording attached (``latest_telemetry``), first;
* photos: the runtime's new captures, looked for on every report, stamped with the board time their
  last CAMERA_CHUNK arrived;
* sequence gaps, decode errors, re-sent requests, reconnects: the client's ``LinkStats`` counters,
  compared on every report.

Two threads share the work. The link's callbacks (on the event loop) only hand what happened, with
the board time it happened at, to the recording's writer thread (:class:`host.run.log_writer.LogWriter`:
one consumer, a bounded FIFO, so the MCAP gets it in the order it happened); the thread does every
:class:`RunLog` call: forward kinematics for ``/tf``, JSON, the chunks' compression, building the
robot's scene (first thing, while the session starts) and reading photos. What reads the shell's
and the runtime's state (the timeline, the captures list, the link's counters) stays on the loop,
noted from the callback and done after it in slices of about :data:`DRAIN_SLICE_S`
(:class:`host.link.deferred.DeferredWork`), and hands its findings to the thread the same way.

Why: the per-vertex scene message of an arm with meshes took 0.25-0.3 s on the loop, and the board's
200 ms watchdog tripped (``ghostshell run --robot mesh_arm``: 2 trips); before that a profile of a
realtime run had shown the MCAP writes inside the link's read callback as half of that callback
(``bench/bench_latency.py``). Now the loop's share of a report is a few queue puts
(``bench/bench_recording.py`` measures both sides).

Bounded: past :data:`host.run.log_writer.MAX_QUEUED` calls waiting, a call is dropped and counted
(:attr:`Recording.dropped`, for the run's summary); :meth:`Recording.close` waits at most
:data:`CLOSE_TIMEOUT_S` wall seconds for the thread to finish the file (longer: one warning, and the
MCAP is cut where the thread was; its chunks up to there are readable).

Nothing here can end a run: a failure of the recording is one warning line and the recording stops.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import anyio.to_thread

from host.link import BoardClient
from host.link.deferred import DeferredWork
from host.link.client import FaultEvent
from host.runtime.robot_runtime import RobotRuntime
from host.run.artefacts import BoardCall
from host.run.log_writer import LogWriter
from host.run.mcap_log import McapError, RunLog
from host.shell import Shell
from host.shell.types import BUILTINS
from protocol.messages import CameraChunk, Message, Nack, SimState, Telemetry
from robots.description import Robot

__all__ = ["CLOSE_TIMEOUT_S", "DRAIN_SLICE_S", "POLL_S", "Recording"]

log = logging.getLogger("host.run")

#: board seconds between looks at the shell's timeline and the runtime's captures
POLL_S = 0.05
#: noted callbacks waiting for the loop beyond which the recording's work is done at once
MAX_DEFERRED = 4096
#: wall seconds of noted work per pass of the event loop; the rest waits for the next pass
DRAIN_SLICE_S = 0.0005
#: wall seconds :meth:`Recording.close` waits for the writer thread to finish the MCAP
CLOSE_TIMEOUT_S = 10.0
#: wall seconds the session waits for the scene's build and first send before it streams (:meth:`Recording.ready`)
READY_TIMEOUT_S = 10.0


class Recording:
    """One session's recording (see the module docstring); create with :meth:`start`."""

    def __init__(self, run_log: RunLog, client: BoardClient, runtime: RobotRuntime, shell: Shell) -> None:
        self.run_log = run_log
        self.client = client
        self.runtime = runtime
        self.shell = shell
        self.live: Any = None  # host.run.foxglove_live.LiveServer while serving
        self.notes: list[str] = []  # the warnings printed (for reports and tests)
        self._poll_at = -1.0
        self._started: set[tuple[float, str]] = set()
        self._ended: set[tuple[float, str]] = set()
        self._captures = len(runtime.captures)
        s = client.stats
        self._stats = (s.seq_gaps, s.decode_errors, s.retries, s.reconnects)
        self._failed = False
        self._chunk_us: int | None = None  # board time the latest camera chunk arrived
        self._work = DeferredWork(slice_s=DRAIN_SLICE_S, max_deferred=MAX_DEFERRED)  # loop-side bookkeeping
        self.writer = LogWriter().start()  # every RunLog call, in order (module docstring)
        self.writer.submit(self._guard, run_log.prepare)  # the scene (MJCF compile) first, off the loop
        first = getattr(client, "latest_telemetry", None)  # a report that came before the recording did
        if isinstance(first, Telemetry):
            self._log(run_log.on_message, first)
            sim = getattr(client, "latest_sim_state", None)
            if isinstance(sim, SimState) and sim.board_time_us == first.board_time_us:
                self._log(run_log.on_message, sim)
        client.on_fault.append(self._on_fault)
        client.on_nack.append(self._on_nack)
        client.on_sent.append(self._on_sent)
        client.on_received.append(self._on_received)

    @classmethod
    def start(cls, path: Path | None, robot: Robot, client: BoardClient, runtime: RobotRuntime, shell: Shell, *,
              live_port: int | None = None, meta: Mapping[str, str] | None = None) -> Recording | None:
        """Record to ``path`` (None: no MCAP) and serve live on ``live_port`` (None: no live view).

        An MCAP that cannot be written or a port that is taken is one warning line (stderr), and the
        run goes on without it; None when neither remains.
        """
        notes: list[str] = []
        run_log = RunLog(robot, (meta or {}).get("scene"))
        if path is not None:
            try:
                run_log.open(path, meta)
            except McapError as e:
                notes.append(f"ghostshell: no run.mcap: {e}; the run goes on without it")
        live = None
        if live_port is not None:
            from host.run.foxglove_live import LiveError, start_live

            try:
                live = start_live(run_log, live_port)
            except LiveError as e:
                notes.append(f"ghostshell: {e}; the run goes on without it")
        for note in notes:
            log.warning("%s", note)
        if run_log.writer is None and live is None:
            run_log.close()
            return None
        rec = cls(run_log, client, runtime, shell)
        rec.notes = notes
        rec.live = live
        if live is not None:
            print(live.banner, file=sys.stderr, flush=True)
        return rec

    @property
    def dropped(self) -> int:
        """Recording calls dropped because the writer thread had :data:`~host.run.log_writer.MAX_QUEUED`
        waiting (0 in a healthy run; the run's summary can show it)."""
        return self.writer.dropped

    async def ready(self, timeout_s: float = READY_TIMEOUT_S) -> bool:
        """Wait (in a worker thread, the loop free) until the writer did what was handed to it so far: the
        scene's build and its one ``/scene`` message (:meth:`RunLog.prepare`), which hold the GIL for tens of
        ms on a mesh robot. The session awaits this before it streams a frame, so that work never lands on
        the control path. False when ``timeout_s`` wall seconds passed first (the run goes on)."""
        return await anyio.to_thread.run_sync(self.writer.wait_idle, timeout_s)

    # -- listening ------------------------------------------------------------------------------
    def _log(self, fn: Callable[..., Any], *args: Any) -> None:
        """Do ``fn(*args)`` (a RunLog call, guarded) on the writer thread, after everything handed before."""
        if not self._failed:
            self.writer.submit(self._guard, fn, *args)

    def _note(self, fn: Callable[..., Any], *args: Any) -> None:
        """Do ``fn(*args)`` (loop-side bookkeeping, guarded) from the loop soon, after what was noted before."""
        if not self._failed:
            self._work.note(self._guard, fn, *args)

    def _drain(self) -> None:
        """Do all the noted work now, in order."""
        self._work.drain()

    def _on_received(self, msg: Message) -> None:
        if isinstance(msg, CameraChunk):  # a photo is complete when its last chunk came: that is its time
            self._chunk_us = self.client.board_now_estimate()
        if isinstance(msg, Telemetry):  # (the link's counters as of this report: later messages change them)
            self._log(self.run_log.on_message, msg)
            s = self.client.stats
            self._note(self._after_report, msg, self._chunk_us, (s.seq_gaps, s.decode_errors, s.retries, s.reconnects))
        elif isinstance(msg, SimState):
            self._log(self.run_log.on_message, msg)

    def _guard(self, fn: Any, *args: Any) -> None:
        if self._failed:
            return
        try:
            fn(*args)
        except Exception as e:  # a recording bug or a dead sink must not end the run
            self._failed = True
            note = f"ghostshell: the recording stopped: {type(e).__name__}: {e}"
            self.notes.append(note)
            log.warning("%s", note)

    def _after_report(self, tel: Telemetry, chunk_us: int | None, counters: tuple[int, int, int, int]) -> None:
        self._link_stats(tel.board_time_us, counters)
        t = tel.board_time_us * 1e-6
        if len(self.runtime.captures) > self._captures:
            self._poll_captures(t if chunk_us is None else chunk_us * 1e-6)
        if t - self._poll_at >= POLL_S:
            self._poll_at = t
            self._poll_calls()

    def _link_stats(self, board_time_us: int, now: tuple[int, int, int, int]) -> None:
        """``now``: the link's (seq_gaps, decode_errors, retries, reconnects) when the report arrived."""
        if now == self._stats:
            return
        gaps, errors, retries, reconnects = (a - b for a, b in zip(now, self._stats))
        self._stats = now
        s = self.client.stats
        if gaps > 0:
            self._log(self.run_log.on_gap, board_time_us, gaps, now[0])
        if errors > 0:
            self._log(self.run_log.link_note, f"{errors} undecodable frame(s) discarded ({s.last_decode_error})",
                      board_time_us)
        if retries > 0:
            self._log(self.run_log.link_note, f"{retries} request(s) re-sent (no ACK/NACK in time)", board_time_us)
        if reconnects > 0:
            self._log(self.run_log.link_note, f"link re-established (reconnect #{now[3]})", board_time_us)

    def _poll_calls(self) -> None:
        result = self.shell.last_result
        if result is None:
            return
        t0 = result.t0
        board = self.runtime.board_times
        for r in result.timeline:
            key = (t0, r.path)
            measured = board.get(r.path, [None, None])
            ended = r.end is not None and r.outcome != "pending"
            # a start line once the board time it started at is known (a robot call's shell start is its
            # release, maybe behind calls queued on its channel; a wait/async scope starts when the shell says)
            known = measured[0] is not None or ended or r.function in BUILTINS
            if r.start is not None and key not in self._started and known:
                self._started.add(key)
                start = measured[0] if measured[0] is not None else t0 + r.start
                self._log(self.run_log.on_call_start, r.path, r.function, r.channel, dict(r.args), start)
            if ended and key not in self._ended:
                self._ended.add(key)
                end = measured[1] if measured[1] is not None else t0 + r.end
                self._log(self.run_log.on_call_end, r.path, r.function, r.channel, r.outcome, r.error, end)
                if r.start is not None:  # its Event now, at its end (on_turn_end gives the calls that had none)
                    start = measured[0] if measured[0] is not None else t0 + r.start
                    self._log(self.run_log.on_call, BoardCall(r.function, r.channel, dict(r.args), r.path, start, end,
                                                              r.outcome, r.error))
                if r.function == "speak" and r.start is not None:
                    start = measured[0] if measured[0] is not None else t0 + r.start
                    self._log(self.run_log.on_speech, str(r.args.get("text", "")), start, end, r.outcome, r.path)

    def _poll_captures(self, t: float) -> None:
        caps = self.runtime.captures
        frame_id = self.runtime.robot.peripherals.camera or "camera"
        while self._captures < len(caps):
            path = caps[self._captures]
            self._captures += 1
            self._log(self._image, t, Path(path), frame_id)

    def _image(self, t: float, path: Path, frame_id: str) -> None:
        """(writer thread) A photo's PNG read from ``path`` and logged; a file gone since is skipped."""
        try:
            png = path.read_bytes()
        except OSError:
            return
        self.run_log.on_image(t, png, frame_id=frame_id)

    # -- callbacks --------------------------------------------------------------------------------
    def _on_sent(self, seq: int, msg: Message) -> None:
        self._log(self.run_log.on_frame_sent, seq, msg, self.client.board_now_estimate())

    def _on_fault(self, ev: FaultEvent) -> None:
        self._log(self.run_log.on_fault, ev.board_time_us, int(ev.raised), int(ev.cleared))

    def _on_nack(self, nack: Nack) -> None:
        self._log(self.run_log.on_nack, nack, self.client.board_now_estimate())

    def on_turn_end(self, calls: Sequence[Any]) -> None:
        """The turn's board-measured calls (``host.run.artefacts.BoardCall``) as Events; the timeline's
        last changes first (after the work still noted). Handed to the writer thread; returns at once."""
        self._drain()
        self._guard(self._poll_calls)
        result = self.shell.last_result
        for c in calls:
            if result is None or (result.t0, c.path) not in self._ended:
                self._log(self.run_log.on_call, c)
        self._log(self.run_log.flush)

    def close(self) -> None:
        """Stop the live view, finish the MCAP, drop the callbacks. Idempotent."""
        listeners: list[tuple[list[Any], Any]] = [
            (self.client.on_fault, self._on_fault), (self.client.on_nack, self._on_nack),
            (self.client.on_sent, self._on_sent), (self.client.on_received, self._on_received)]
        for lst, cb in listeners:
            if cb in lst:
                lst.remove(cb)
        self._drain()
        self._log(self.run_log.close)  # on the writer thread, after everything handed before it
        finished = self.writer.close(CLOSE_TIMEOUT_S)
        if not finished:
            note = (f"ghostshell: the recording did not finish within {CLOSE_TIMEOUT_S:g} s "
                    f"({self.writer.waiting()} call(s) left); run.mcap ends where it got to")
            self.notes.append(note)
            log.warning("%s", note)
        if self.writer.dropped:
            note = f"ghostshell: the recording dropped {self.writer.dropped} call(s) (its writer thread fell behind)"
            self.notes.append(note)
            log.warning("%s", note)
        if self.live is not None:
            self.live.stop()
            self.live = None
        if finished:
            self.run_log.close()  # (done already on the thread; idempotent)
