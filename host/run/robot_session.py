"""A persistent robot session: one board, one link, one robot runtime, one :class:`Shell`, many turns.

``RobotSession`` is an async context manager. Entering it loads the robot
(``SessionOptions.robot``, :func:`robots.registry.load_robot`), starts the emulated
board for it (``python -m firmware_sim --robot ...`` on a pty, or connects to ``link``
and checks in the handshake that the board drives the same robot), the link
client, the robot runtime, the registry and one shell, and runs the telemetry
pump, the silence watchdog and (in realtime) the top-up task in a task group
that lives as long as the session. Each :meth:`RobotSession.run_turn` runs one
LLM output stream (or a complete program) on that shell and writes the turn's
artefacts (timeline.json/png, joints.png, summary.json) to its own folder;
the frame logs of the whole session stay in the session folder.

Example::

    async with RobotSession(SessionOptions(out=Path("runs/chat"), lockstep=True)) as s:
        turn = await s.run_turn('<head_act action="nod"/>Hello.')
        print(turn.result.timeline.table(), turn.executed_text)

Failures: a link or LLM failure inside the session's tasks surfaces from the
``async with`` as that :class:`~host.link.errors.LinkError` /
:class:`~host.ghost.GhostError` (not an exception group).

Board faults: at start a WATCHDOG_FAULT latched by the previous host's missing
heartbeat is cleared with ESTOP_CLEAR (a logged note); a board in ESTOP is refused
with :class:`~host.link.errors.BoardFaulted` (see :mod:`host.link.faultcheck`). A
fault the board raises during a turn (ESTOP, WATCHDOG_FAULT), or servo frames it
refuses (NACK ESTOPPED / FAULT_LATCHED), fail the streamer
(:meth:`~host.motion.streamer.FrameStreamer.fail`): the running calls fail with the
reason and the turn's outcome is ``failed`` (``extra.board_fault`` in summary.json).

Stops (:mod:`host.run.stops`): :meth:`RobotSession.request_stop` interrupts the running turn
through the shell's lifecycle tree (and every later turn at its start) for a signal or a bound;
:meth:`RobotSession.go_to_rest` then moves the robot smoothly to its rest pose. Bounds:
``SessionOptions.max_board_s`` per turn (board seconds from the turn's start) and
``max_log_mb`` for the session's frame logs (checked every 0.25 s of wall time).

Deadlines: every wait of the session's work ends by telemetry or by a deadline. A stop (signal,
bound, stall) gives the graceful rest ``SessionOptions.stop_grace_s`` wall seconds
(:data:`host.run.stops.STOP_GRACE_S`): then the turn still running is cut (its resets aborted, its
calls as far as they got), the settle and the rest pose get only what is left of it, and a stop while
the session starts cuts the start-pose move at once. The no-progress guard
(:mod:`host.run.progress_guard`, ``SessionOptions.progress_limit_s``) stops work that moves nothing
(board time, frames, calls) with outcome ``stalled`` and a line naming what it waited for.

Timing health: each turn's ``summary.json`` has ``extra.timing`` (:meth:`RobotSession.timing`): the
event loop's lag p50/p99/max (:mod:`host.run.loop_lag`), frames late and skipped, watchdog trips and
the recording's dropped messages.
"""

from __future__ import annotations

import contextlib
import functools
import logging
from collections.abc import AsyncIterable, AsyncIterator, Awaitable, Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import anyio
import anyio.abc
import anyio.to_thread

from host.ghost import GhostError
from host.link import BoardClient
from host.link.board_process import BoardProcess
from host.link.errors import BoardFaulted, LinkConfigError, LinkError
from host.link.faultcheck import LATCHED, ServoFaulted, clear_command, refusal_message
from host.link.client import FaultEvent, LinkTarget
from host.run import artefacts
from host.run.events import Event, EventMonitor, EventPolicy
from host.run.session_events import SessionEvents
from host.run.turn_summary import TurnSummaries, TurnView, board_calls, fell, pose
from host.run.effort_limits import effort_limits
from host.run.turn_gc import frozen_heap
from host.motion.stalls import STALLS
from host.runtime.link import ClientLink
from host.runtime.robot_runtime import RobotRuntime, warm_up_behaviours
from host.run.loop_lag import LagMonitor
from host.run.options import SessionOptions
from host.run.progress_guard import ProgressGuard
from host.run.stop_control import StopControl, session_guard
from host.run.stops import Interrupted, StopReason
from host.run.priority import raise_host_priority
from host.run.assembly import build_runtime, build_shell, first_report, mount_servers
from host.run.launch import LinkPlan, board_args, connect_client, launch_board
from host.run.recording import Recording
from host.run.turn_files import turn_plotter, turn_writer
from host.run.pump import (
    TELEMETRY_SILENCE_S,
    BoardPacer,
    Recorder,
    buffered,
    go_to_pose,
    pump,
    realtime_topper,
    silence_watchdog,
    timed_chunks,
)
from host.shell import Shell
from host.shell.cleanups import Cleanups
from host.shell.timeline import Observation, RunResult, Timeline
from protocol.linkspec import LinkSpec, parse_link_spec
from protocol.messages import FaultFlags, Nack, NackReason
from robots.description import Robot
from robots.registry import load_robot

log = logging.getLogger("host.run")


#: wall seconds between two checks of the frame logs' size (``max_log_mb``)
LOG_CHECK_S = 0.25
#: Wall seconds the link client's close at the session's end may take before it is cancelled
#: (:meth:`RobotSession._close_client`). The close cancels its background tasks once and waits for them; on Python
#: 3.11 ``asyncio.wait_for`` drops a cancellation that arrives together with the awaited reply, so a
#: TIME_SYNC exchange in flight could outlive the cancel and the close waited for ever (the run never
#: wrote its summary: the task-12 hang). Cancelling the close makes asyncio's TaskGroup cancel its
#: tasks a second time, which ends them.
CLOSE_TIMEOUT_S = 5.0


@dataclass
class _TurnStart:
    """What :meth:`RobotSession.run_turn` knew when its turn began (the turn's artefacts need it)."""

    label: str
    out: Path
    token_times: list[tuple[float, str]]
    board_t0: float
    base_start: Any
    tilt_from: int
    n_captures: int


@dataclass
class TurnResult:
    """What one turn did (also written to its folder).

    ``executed_text`` is the reply as it was actually executed: the function
    tokens dispatched and the sentences whose speech started, closed
    well-formed; for an interrupted turn, nothing after the cut.
    ``pose_start``/``pose_end`` are ``[x m, y m, yaw deg]`` of the base.
    """

    result: RunResult
    calls: list[artefacts.BoardCall]
    summary: artefacts.Summary
    out: Path
    token_times: list[tuple[float, str]] = field(default_factory=list)
    board_t0: float = 0.0
    executed_text: str = ""
    received_text: str = ""
    #: the events of this turn that were not ignored (host.run.events), and the one that interrupted it
    events: list[Event] = field(default_factory=list)
    interrupted_by: Event | None = None

    @property
    def interrupted(self) -> bool:
        """True when the turn was cut by :meth:`RobotSession.interrupt`."""
        return self.result.interrupted

    @property
    def observations(self) -> list[Any]:
        """The shell's observations of this turn."""
        return list(self.result.observations)


def _first_cause(group: BaseExceptionGroup) -> Exception | None:
    """The link or LLM error behind a task group's failure, if that is what it was."""
    for exc in group.exceptions:
        if isinstance(exc, BaseExceptionGroup):
            found = _first_cause(exc)
            if found is not None:
                return found
        elif isinstance(exc, (LinkError, GhostError)):
            return exc
    return None


class RobotSession:
    """One robot, one shell, many turns (see the module docstring)."""

    def __init__(self, opts: SessionOptions) -> None:
        self.opts = opts
        #: the robot this session drives (loaded at construction: a bad --robot fails before anything starts)
        self.robot: Robot = load_robot(opts.robot, opts.robots_dir)
        #: the vocabulary shown in the prompt and the scene of the board's world
        self.vocabulary = opts.vocabulary or self.robot.interface.default
        self.scene = opts.scene or self.robot.default_scene
        self.out = opts.out
        self.rec = Recorder()
        self.turns = 0
        self._board: BoardProcess | None = None
        self._stack = contextlib.AsyncExitStack()
        self._tg: anyio.abc.TaskGroup | None = None
        self.client: BoardClient | None = None
        self._runtime: RobotRuntime | None = None
        self._shell: Shell | None = None
        self._turn: _TurnStart | None = None  # the turn in progress
        self._link_tried = False  # a board link was attempted (a failure from then on has a report)
        #: the teardown had to be cancelled after CLOSE_TIMEOUT_S (see there)
        self.close_timed_out = False
        self.recording: Recording | None = None  # run.mcap and the live view (host.run.recording)
        self.mounts: list[Any] = []  # the mounted MCP servers (host.mounts.McpMount)
        #: the session's events: watched on every report, handled as the policy says (host.run.session_events)
        self.events = SessionEvents(opts.event_policy or EventPolicy(), self.robot.channels, lambda: self._shell)
        #: builds each turn's summary.json (host.run.turn_summary)
        self.summaries = TurnSummaries(self.robot, opts, self.vocabulary, self.rec, self.scene_report, self._clock_mode)
        #: the stop's reason, its deadline and the work it cuts (host.run.stop_control)
        self.stops = StopControl(opts.stop_grace_s, self._interrupt_running, self.abort_cleanups)
        #: the event loop's scheduling delay, sampled while the session runs (reset at each turn's start)
        self.lag = LagMonitor()
        self._host_nice: int | None = None  # a realtime run's host priority (host.run.priority)
        self.guard: ProgressGuard | None = None
        self._board_s0: float | None = None  # the board time of the session's first report (s)
        self._late0 = 0  # the board's late count at the turn's start

    # -- life cycle ------------------------------------------------------------------------------
    @property
    def runtime(self) -> RobotRuntime:
        """The robot runtime (only inside the session)."""
        if self._runtime is None:
            raise RuntimeError("the robot session is not started")
        return self._runtime

    @property
    def board(self) -> BoardProcess | None:
        """The emulated board's process while the session runs (None when connected to a given board)."""
        return self._board

    @property
    def shell(self) -> Shell:
        """The session's one shell (only inside the session)."""
        if self._shell is None:
            raise RuntimeError("the robot session is not started")
        return self._shell

    async def __aenter__(self) -> RobotSession:
        """Bring the session up, one step after the other (each below; :mod:`host.run.launch`,
        :mod:`host.run.assembly`); a failure on the way tears down what was started, in reverse."""
        created = not self.out.exists()
        self.out.mkdir(parents=True, exist_ok=True)
        spec = parse_link_spec(self.opts.link) if isinstance(self.opts.link, str) else self.opts.link
        try:
            plan = LinkPlan.of(spec, self.opts, self.robot)
            target = await self._launch_board(plan)
            self._link_tried = True
            self._warm_up()
            client = await self._connect(plan, target)
            frame_link = await self._assemble(client, plan)
            await self._start_recording(client, plan.spec)
            await self._start_tasks(client, frame_link)
            await self._go_to_start_pose()
            self.stops.up = True
        except BaseException as exc:
            await self.__aexit__(type(exc), exc, exc.__traceback__)
            if created and isinstance(exc, LinkConfigError):  # nothing ran: leave no empty run folder behind
                with contextlib.suppress(OSError):
                    self.out.rmdir()
            raise
        return self

    async def __aexit__(self, et: type[BaseException] | None, exc: BaseException | None,
                        tb: TracebackType | None) -> bool | None:
        if self._tg is not None:
            self._tg.cancel_scope.cancel()
        try:
            await self._stack.__aexit__(et, exc, tb)
        except BaseExceptionGroup as group:  # one task's failure cancels the rest: report the cause
            cause = _first_cause(group)
            if cause is None:
                raise
            raise cause from group
        finally:
            self._tg = None
            if self.recording is not None:
                self.recording.close()
            if self._board is not None:
                self._board.stop()
                self._board = None
        return None

    async def _launch_board(self, plan: LinkPlan) -> LinkTarget:
        """Start the emulated board when the plan says so; returns what the client connects to."""
        if not plan.emulate:
            return plan.spec
        args = board_args(self.opts, self.robot, self.out, self.scene, plan.log_suffix)
        self._board = await launch_board(args, self.out / "board.stderr", plan.spec)
        return self._board.link_target()  # never reconnects to the pty of a board that died

    def _warm_up(self) -> None:
        """One-time planning costs now, not on the first call's token -> servo path; before the link is up,
        because it holds the event loop and a board whose link is up expects heartbeats."""
        warm_up_behaviours(self.robot)
        if self.opts.plots:
            artefacts.warm_up_plotting()  # the turn's plots run in a thread while the link is live

    async def _connect(self, plan: LinkPlan, target: LinkTarget) -> BoardClient:
        """Connect and enter the link client; its close joins the teardown (:meth:`_close_client`)."""
        client = await connect_client(plan, target, baud=self.opts.baud, board=self._board, faults=self.opts.faults,
                                      log_path=self.out / f"host_frames{plan.log_suffix}")
        self.client = await client.__aenter__()
        self._stack.push_async_exit(functools.partial(self._close_client, client))
        return client

    async def _assemble(self, client: BoardClient, plan: LinkPlan) -> ClientLink:
        """The runtime, the shell and the mounted MCP servers on the connected ``client``
        (:mod:`host.run.assembly`); returns the runtime's frame link."""
        tel = await first_report(client, plan, board_started_here=self._board is not None)
        self._board_s0 = tel.board_time_us * 1e-6
        self._late0 = tel.late_count
        runtime, frame_link = build_runtime(self.robot, client, plan, self.out, tel)
        self._runtime = runtime
        client.on_fault.append(self._on_fault)
        client.on_nack.append(self._on_nack)
        self._shell = build_shell(self.robot, runtime, self.vocabulary, self.opts)
        if self.opts.mcp_mounts:
            self.mounts = await self._stack.enter_async_context(
                mount_servers(self.opts, self._shell.registry, runtime, client.lockstep))
            for m in self.mounts:
                for note in m.notes:
                    log.warning("%s", note)
        return frame_link

    async def _start_recording(self, client: BoardClient, spec: LinkSpec) -> None:
        """run.mcap and the live view (:class:`Recording`): the scene's build and its /scene message, before any frame."""
        self.recording = Recording.start(self.out / "run.mcap" if self.opts.mcap else None, self.robot, client,
                                         self.runtime, self.shell, live_port=self.opts.foxglove,
                                         meta=self._mcap_meta(spec))
        if self.recording is not None:
            await self.recording.ready()

    async def _start_tasks(self, client: BoardClient, frame_link: ClientLink) -> None:
        """The session-long task group (left first at teardown): the telemetry pump, the silence watchdog,
        in realtime the top-up (and a slow line's pacing), the bounds, the loop-lag sampler, the progress guard."""
        opts, runtime = self.opts, self.runtime
        tg = anyio.create_task_group()
        self._tg = await self._stack.enter_async_context(tg)
        self.events.watch(EventMonitor(self.robot.servos.names, self.robot.base.floating,
                                     _targets_at(runtime.streamer.history), limits=effort_limits(self.robot),
                                     joints=[s.joint for s in self.robot.servos]), client)
        tg.start_soon(self._ends_the_run, pump(client, runtime, self.rec, [self.events.on_report]))
        if opts.events:
            tg.start_soon(self.events.play, runtime.streamer, runtime.board_now_s(), opts.events)
        tg.start_soon(self._ends_the_run, silence_watchdog(runtime, self.rec, client))
        if not client.lockstep:
            self._host_nice = raise_host_priority()  # the loop is the control path (host.run.priority)
            tg.start_soon(self._ends_the_run, realtime_topper(runtime))
            if client.tx_wire is not None:  # a slow line the host models: lookahead frames yield to new calls
                tg.start_soon(self._ends_the_run, frame_link.pace())
        if opts.max_log_mb is not None:
            tg.start_soon(self._log_bound, opts.max_log_mb)
        tg.start_soon(self.lag.run)
        if opts.progress_limit_s is not None:
            self.guard = self._progress_guard(opts.progress_limit_s)
            tg.start_soon(self.guard.run)

    async def _go_to_start_pose(self) -> None:
        """Fill the lookahead, then move to the start pose; a stop while starting cuts the move at once."""
        runtime = self.runtime
        await runtime.streamer.top_up()
        pose = self.opts.start_pose or self.robot.start_pose
        with self.stops.work(f"moving to the start pose {pose!r}") as scope:
            await go_to_pose(runtime, pose)
        if scope.cancelled_caught:  # a stop while starting: the turn is cut at its start
            log.warning("the move to the start pose %r was cut: %s", pose, self.stop.message if self.stop else "")

    async def _close_client(self, client: BoardClient, *exc: object) -> None:
        """Close the link client within ``CLOSE_TIMEOUT_S`` wall seconds (see there); a close that
        did not end by then is cancelled, which ends it, and noted (``close_timed_out``)."""
        with anyio.move_on_after(CLOSE_TIMEOUT_S) as closing:
            await client.__aexit__(*exc)
        if closing.cancelled_caught:
            log.warning("the link client did not close within %g s (a link task outlived its cancellation); "
                        "cancelled its close", CLOSE_TIMEOUT_S)
            self.close_timed_out = True

    async def _ends_the_run(self, task: Awaitable[None]) -> None:
        """Run a session task whose :class:`LinkError` ends the run (the pump, the silence watchdog,
        the realtime top-up).

        Before the error cancels the session, the streamer is failed with it: nothing will confirm
        frames or board time any more, so the shielded resets of the calls being cancelled (a
        music stop, a motion's return) fail at once with the reason instead of each waiting out
        its reset timeout.
        """
        try:
            await task
        except LinkError as exc:
            if self._runtime is not None:
                self._runtime.streamer.fail(exc)
            raise

    # -- stops -----------------------------------------------------------------------------------
    def request_stop(self, stop: StopReason) -> bool:
        """Stop the session's work early (a signal, a bound, a stall): the running turn is interrupted
        through the shell's lifecycle tree, as an external interruption is, and any later turn is
        interrupted at its start. The first reason is kept, and starts the stop's deadline
        (``SessionOptions.stop_grace_s`` wall seconds, :class:`host.run.stop_control.StopControl`). Returns
        False while the session is still starting (nothing to interrupt gracefully: the move to the start
        pose is cut at once), else True."""
        return self.stops.request(stop, self._tg)

    @property
    def stop(self) -> StopReason | None:
        """Why the session stops early, once :meth:`request_stop` was called (None: it does not)."""
        return self.stops.reason

    @property
    def stop_overdue(self) -> bool:
        """The stop's deadline passed: what remains of the graceful stop is cut or skipped."""
        return self.stops.overdue

    def stop_left_s(self) -> float:
        """Wall seconds left until the stop's deadline (``inf`` while no stop was requested, 0 once it passed)."""
        return self.stops.left_s()

    def _progress_guard(self, limit_s: float) -> ProgressGuard:
        """The session's no-progress guard over board time, frames and calls (:func:`session_guard`)."""
        rec = self.rec
        return session_guard(limit_s, self.stops, self.request_stop, lambda: rec.t[-1] if rec.t else None,
                             lambda: self.client.stats.servo_frames_sent if self.client is not None else 0,
                             lambda: self._shell, lambda: self._runtime)

    def _interrupt_running(self) -> None:
        if self._shell is not None and self._shell.running:
            self._shell.interrupt()

    def abort_cleanups(self) -> None:
        """A forced stop (a second signal): the shell's resets and the runtime's peripheral stops that the
        cancelled turn is still running are cut short, so the command exits at once instead of after
        their shielded timeouts (5 s each). The caller cancels the turn itself."""
        if self._shell is not None:
            self._shell.abort_cleanups()
        if self._runtime is not None:
            self._runtime.abort_cleanups()

    def clear_stop(self) -> None:
        """Forget a stop (e.g. a board-time bound that ended one MCP program): later turns run again, and
        its deadline no longer cuts them."""
        if self.stops.clear() and self._runtime is not None:  # the deadline aborted its cleanups: re-arm them
            self._runtime._cleanups = Cleanups()  # (RobotRuntime has no public reset; a fresh one is unaborted)

    async def go_to_rest(self, timeout_s: float = 10.0) -> bool:
        """Move every servo smoothly to the robot's rest pose (``robot.toml`` ``rest_pose``), e.g. after a
        stop; returns False when it could not within ``timeout_s`` wall seconds, or within what is left
        of a stop's deadline (:meth:`stop_left_s`; none left: not tried), or the link is down, the board
        refuses motion, ..."""
        runtime, client = self._runtime, self.client
        if runtime is None or client is None or not client.connected or runtime.streamer.failure is not None:
            return False
        timeout_s = min(timeout_s, self.stop_left_s())
        if timeout_s <= 0:
            log.warning("no time left of the stop's %g s for the rest pose: not tried", self.opts.stop_grace_s)
            return False
        with anyio.move_on_after(timeout_s) as scope, self.stops.work(f"moving to the rest pose {self.robot.rest_pose!r}"):
            try:
                await go_to_pose(runtime, self.robot.rest_pose)
            except (LinkError, BoardFaulted):
                return False
            return True
        if scope.cancelled_caught:
            log.warning("the rest pose %r was not reached within %.1f s", self.robot.rest_pose, timeout_s)
        return False

    def log_bytes(self) -> int:
        """The size of the session's frame logs (host and board) so far, in bytes."""
        total = 0
        for path in self.out.glob("*_frames.*"):
            try:
                total += path.stat().st_size
            except OSError:
                pass
        return total

    async def _log_bound(self, max_mb: float) -> None:
        limit = max_mb * 1e6
        while True:
            await anyio.sleep(LOG_CHECK_S)
            size = self.log_bytes()
            if size > limit:
                self.request_stop(StopReason("limit", "max_log_mb", (
                    f"the frame logs reached {size / 1e6:.1f} MB, over the bound of {max_mb:g} MB (--max-log-mb)")))
                return

    async def _board_time_bound(self, at_s: float, max_s: float) -> None:
        try:
            await self.runtime.streamer.wait_board_time(int(at_s * 1e6))
        except BoardFaulted:
            return
        self.request_stop(StopReason("limit", "max_board_s", (
            f"the turn reached its board-time bound of {max_s:g} s (--max-board-s)")))

    def _clock_mode(self) -> str:
        """"lockstep" or "realtime": the board's clock as its CAPS said once connected (a board you started
        keeps its own, whatever ``--lockstep`` says), else the one asked for."""
        lockstep = self.client.lockstep if self.client is not None else self.opts.lockstep
        return "lockstep" if lockstep else "realtime"

    def _mcap_meta(self, spec: LinkSpec) -> dict[str, str]:
        return {"scene": self.scene, "vocabulary": self.vocabulary, "link": str(spec), "label": self.opts.task_label,
                "clock_mode": self._clock_mode()}

    # -- board faults ----------------------------------------------------------------------------
    def _how_to_clear(self) -> str:
        return f"clear it with `{clear_command(self.client.link_spec if self.client is not None else 'SPEC')}`"

    def _on_fault(self, ev: FaultEvent) -> None:
        """An ESTOP raised mid-run fails the running calls and the turn (the session stays up).

        A watchdog fault latched mid-run is not handled here: it means the link was silent past
        the watchdog and the crouch delay, and the telemetry pump ends the run with one message
        (:func:`host.run.pump.watchdog_fault_message`); one left over from a previous host is
        cleared at connect (:func:`host.link.faultcheck.clear_leftover_fault`).
        """
        if ev.raised & FaultFlags.ESTOP and self._runtime is not None:
            self._runtime.streamer.fail(BoardFaulted(
                f"the board raised ESTOP at board time {ev.board_time_us / 1e6:.3f} s and refuses motion; "
                + self._how_to_clear()))

    def _on_nack(self, nack: Nack) -> None:
        """Servo frames refused because of an ESTOP fail the turn at once (before telemetry shows it)."""
        if nack.reason == NackReason.SERVO_FAULT and self.client is not None and self._runtime is not None:
            # worded when shown, from every NACK by then (host.link.faultcheck.servo_fault_message)
            self._runtime.streamer.fail(ServoFaulted(self.client))
            return
        message = refusal_message(nack, self.client.link_spec if self.client is not None else "SPEC")
        if message is not None and self._runtime is not None:
            self._runtime.streamer.fail(BoardFaulted(message))

    # -- turns -----------------------------------------------------------------------------------
    def pacer(self) -> BoardPacer:
        """A sleep on the board clock for a scripted LLM (absolute deadlines; fresh per turn)."""
        return BoardPacer(self.runtime)

    @property
    def turn_running(self) -> bool:
        """True while a turn runs (:meth:`run_turn` started it and has not returned)."""
        return self._turn is not None

    def background(self) -> anyio.abc.TaskGroup:
        """The session's task group (for a live view or other session-long tasks)."""
        if self._tg is None:
            raise RuntimeError("the robot session is not started")
        return self._tg

    async def run_turn(self, source: str | AsyncIterable[str], *, label: str | None = None, out: Path | None = None,
                       hold: bool = False, buffer: bool = False, interrupt_after: float | None = None,
                       settle_s: float = 0.5, write: bool = True) -> TurnResult:
        """Run one reply (a complete program, or a stream of chunks) and write its artefacts.

        ``hold``: keep a lockstep board still while waiting for each chunk (a real
        LLM); ``buffer``: execute only after the whole reply arrived;
        ``interrupt_after``: interrupt the turn that many board seconds after it
        started; ``settle_s``: board seconds to let motion settle afterwards;
        ``out``: the turn's folder (default ``<session out>/turn_<n>``); ``write=False``
        leaves the writing to the caller (:meth:`write_now` / :meth:`write`).
        """
        runtime, shell = self.runtime, self.shell
        self.turns += 1
        if self.client is not None and not self.client.faults & LATCHED:
            runtime.streamer.clear_failure()  # a fault cleared since the last turn no longer fails calls
        label = label or f"turn {self.turns}"
        out = out if out is not None else self.out / f"turn_{self.turns:02d}"
        n_captures = len(runtime.captures)
        runtime.board_times.clear()
        runtime.run_dir = out
        base_start = self.rec.base[-1] if self.rec.base else None
        start = self._turn = _TurnStart(label, out, [], runtime.board_now_s(), base_start, len(self.rec.base),
                                        n_captures)
        stream: AsyncIterable[str] = _one(source) if isinstance(source, str) else source
        chunks = timed_chunks(stream, runtime.board_now_s, start.token_times, runtime.streamer.hold if hold else None)
        self.lag.reset()  # the turn's timing health covers the turn
        tel = self.client.latest_telemetry if self.client is not None else None
        self._late0 = tel.late_count if tel is not None else self._late0
        with frozen_heap():  # no full GC pass over the loaded host inside the turn (host.run.turn_gc)
            with self.stops.work("running the turn") as work:
                async with anyio.create_task_group() as tg:
                    if interrupt_after is not None:
                        tg.start_soon(self._interrupt_at, start.board_t0 + interrupt_after)
                    if self.stop is not None:  # the session is stopping: this turn is cut at once
                        tg.start_soon(self._interrupt_at, start.board_t0)
                    if self.opts.max_board_s is not None:
                        tg.start_soon(self._board_time_bound, start.board_t0 + self.opts.max_board_s, self.opts.max_board_s)
                    result = await shell.run(buffered(chunks) if buffer else chunks)
                    tg.cancel_scope.cancel()
            if work.cancelled_caught:  # the stop's deadline cut the turn: its calls as far as they got
                result = _cut_result(shell.last_result, start.board_t0, self.opts.stop_grace_s)
            settle_note = await self._settle(settle_s, start.board_t0) if settle_s > 0 else None
        if settle_note is not None:
            result.observations.append(Observation("warning", settle_note, None, runtime.board_now_s()))
        turn = self._turn_result(start, result)
        if settle_note is not None:
            turn.summary.extra["settle"] = settle_note
        self._turn = None
        if self.recording is not None:
            self.recording.on_turn_end(turn.calls)
        if write:
            await self.write(turn, label)
        return turn

    async def _settle(self, settle_s: float, board_t0: float) -> str | None:
        """Let motion settle ``settle_s`` board seconds after a turn; None when it did, else why not.

        A stopped session does not settle (the rest pose it moves to next is its settle). The turn's end
        must end: this runs after the turn's board-time bound was cancelled and may
        run after the session's pump or silence watchdog are gone, so it is bounded twice: in board
        time by the turn's bound (``max_board_s`` from ``board_t0``), in wall time by
        ``settle_s + TELEMETRY_SILENCE_S`` (the silence watchdog's own tolerance: a board that
        reports does reach the settle time sooner in lockstep and in realtime).
        """
        runtime = self.runtime
        if runtime.streamer.failure is not None or self.stop is not None:  # stopping: the rest pose comes next
            return None
        target_s = runtime.board_now_s() + settle_s
        if self.opts.max_board_s is not None:
            target_s = min(target_s, board_t0 + self.opts.max_board_s)
        wall_s = settle_s + TELEMETRY_SILENCE_S
        with anyio.move_on_after(wall_s) as scope:
            self.stops.phase = "settling after the turn"
            try:
                await runtime.streamer.wait_board_time(int(target_s * 1e6))
            finally:
                self.stops.phase = None
        if scope.cancelled_caught:
            log.warning("settling after the turn: board time did not reach %.3f s within %g s", target_s, wall_s)
            return (f"settle cut: board time stayed at {runtime.board_now_s():.3f} s, short of {target_s:.3f} s, "
                    f"for {wall_s:g} s (no telemetry handled)")
        return None

    def _turn_result(self, start: _TurnStart, result: RunResult, link_error: BaseException | None = None) -> TurnResult:
        events, by = self.events.end_turn()
        for ev in events:  # what the next request hears about, like any observation
            result.observations.append(Observation("info", f"event: {ev}", None, ev.board_time_s))
        turn = TurnResult(result, [], None, start.out, start.token_times, start.board_t0,  # type: ignore[arg-type]
                          executed_text=result.executed_text, received_text="".join(c for _, c in start.token_times),
                          events=events, interrupted_by=by if result.interrupted else None)
        turn.calls = board_calls(result, self._runtime)
        captures = self._runtime.captures[start.n_captures:] if self._runtime is not None else []
        view = TurnView(start.label, result, turn.calls, start.board_t0, start.base_start, start.tilt_from, captures,
                        events, turn.interrupted_by)
        turn.summary = self.summaries.summary(view, streamer=self.runtime.streamer, client=self.client, stop=self.stop,
                                              timing=self.timing(), link_error=link_error)
        return turn

    def ended_turn(self, error: BaseException, label: str | None = None, out: Path | None = None) -> TurnResult | None:
        """The turn a link error ended (the session's ``async with`` raised ``error``), as far as it got.

        Its calls are in the state the loss left them: finished ones as they ended, the rest
        ``cancelled`` with ``error`` naming the loss (``link lost while running`` / ``... while
        queued``); ``summary.outcome`` is ``link_lost`` and ``extra.link_error`` the one-line
        message. When the link failed before any turn began (connecting: no TIME_SYNC reply, or
        while going to the start pose), an empty turn labelled ``label`` in ``out`` (default the
        session folder). None when no link was tried, the link could not be opened as specified
        (:class:`LinkConfigError`: a usage error), or the board refused the host at connect
        (:class:`BoardFaulted`: nothing ran). Write it with :meth:`write_now` after the session
        ended: the emulated board has then stopped and printed its fault report
        (``extra.faults.board``).

        ``error`` may also be :class:`host.run.stops.Interrupted` (a signal cancelled the work at
        once): the outcome is then ``interrupted``, ``extra.stopped`` names the signals, and the
        calls cut short say ``stopped by SIGINT while running|queued``; such a turn is reported
        also when the session had not started yet.
        """
        if isinstance(error, LinkConfigError):
            return None
        if self._runtime is None:
            if not isinstance(error, Interrupted) and (not self._link_tried or isinstance(error, BoardFaulted)):
                return None
            return self._bare_turn(error, label or self.opts.task_label, out or self.out)
        start, self._turn = self._turn, None
        if start is None or self._shell is None or self._shell.last_result is None:
            # no turn began (a stop or a loss while starting): the board time streamed since the first report
            t0 = self._board_s0 if self._board_s0 is not None else self._runtime.board_now_s()
            start = _TurnStart(label or self.opts.task_label, out or self.out, [], t0, None,
                               0, len(self._runtime.captures))
            result = RunResult(Timeline(), [], start.board_t0)
        else:
            result = self._shell.last_result
        turn = self._turn_result(start, result, error)
        what = (f"stopped by {error.forced_by}" if isinstance(error, Interrupted) else "link lost")
        for c in turn.calls:
            if c.outcome == "cancelled" and c.error is None:
                c.error = f"{what} while {'running' if c.start is not None else 'queued'}"
        return turn

    def _bare_turn(self, error: BaseException, label: str, out: Path) -> TurnResult:
        """The report of a session whose link failed before the runtime existed (while connecting)."""
        return TurnResult(RunResult(Timeline(), [], 0.0), [], self.summaries.bare(error, label, self.client), out)

    async def _interrupt_at(self, at_s: float) -> None:
        try:
            await self.runtime.streamer.wait_board_time(int(at_s * 1e6))
        except BoardFaulted:
            return  # the board refuses motion: the turn fails on its own
        self.shell.interrupt()

    def interrupt(self, channels: Iterable[str] | None = None) -> int:
        """Interrupt the running turn (all channels, or only ``channels``); returns calls cancelled."""
        return self.shell.interrupt(channels)

    def state(self) -> dict[str, Any]:
        """A snapshot: board time, base pose ``[x, y, yaw deg]``, tilt, fell, running calls per channel."""
        runtime = self.runtime
        b = self.rec.base[-1] if self.rec.base else None
        tilt = artefacts.tilt_deg(b[2]) if b else 0.0
        tl = self.shell.timeline
        running = {} if tl is None else {r.channel or "-": f"{r.function}{r.args}" for r in tl
                                         if r.start is not None and r.end is None}
        return {"board_time_s": round(runtime.board_now_s(), 3), "base": pose(b), "tilt_deg": round(tilt, 2),
                "fell": fell(self.robot, tilt, b[1][2] if b else None, self.rec.base_z0), "running": running, "busy": self.shell.running,
                "skills": [s.name for s in self.shell.skills.list()], "scene": self.scene_report()}

    async def capture(self) -> Path:
        """Take a camera picture now (outside any turn) and return the PNG's path."""
        runtime = self.runtime
        png = await runtime.link.capture(160, 120)
        path = self.out / f"capture_session_{len(runtime.captures) + 1}.png"
        path.write_bytes(png)
        runtime.captures.append(path)
        return path

    def scene_report(self) -> dict[str, Any]:
        """The scene's ground truth now: ``{"name", "objects", "toppled"}`` (the board's SIM_STATE)."""
        s = self.client.latest_sim_state if self.client is not None else None
        return {"name": self.scene, "objects": s.objects if s else 0, "toppled": s.toppled if s else 0}

    def prompt(self, format: str = "xml") -> str:
        """The system prompt (code-as-prompt) of the mounted vocabulary and the saved skills."""
        return self.shell.prompt(format=format)

    # -- artefacts -------------------------------------------------------------------------------

    def timing(self) -> dict[str, Any]:
        """The turn's timing health (``summary.json``'s ``extra.timing``): ``lag`` (the event loop's
        scheduling delay since the turn started, :meth:`host.run.loop_lag.LagMonitor.stats`: p50/p99/max
        in ms and samples n), ``frames_late`` (servo frames the board refused as arriving too late, its
        ``late_count`` since the turn started; None without a report), ``frames_skipped`` (grid frames the
        host left unsent: too late to arrive in time), ``watchdog_trips`` (the board's watchdog holds seen
        in its reports), ``recording_dropped`` (messages the recording dropped: its ``dropped``, else 0),
        ``stop_overdue`` (a stop's deadline cut the work) and ``host_nice`` (the nice value a realtime host
        ran at, :mod:`host.run.priority`; None in lockstep); with ``GHOSTSHELL_STALLS`` set, ``stalls_injected``
        (count and wall seconds, :mod:`host.motion.stalls`)."""
        client, runtime = self.client, self._runtime
        tel = client.latest_telemetry if client is not None else None
        return {"lag": self.lag.stats(),
                "frames_late": max(0, tel.late_count - self._late0) if tel is not None else None,
                "frames_skipped": runtime.streamer.frames_skipped if runtime is not None else None,
                "watchdog_trips": client.fanout.watchdog_holds if client is not None else None,
                "recording_dropped": int(getattr(self.recording, "dropped", 0) or 0),
                "stop_overdue": self.stop_overdue,
                "host_nice": self._host_nice,
                **({"stalls_injected": {"count": STALLS.count, "total_s": round(STALLS.total_s, 3)}}
                   if STALLS is not None else {})}

    def writer(self, turn: TurnResult, label: str, *, plots: bool | None = None) -> Callable[[], None]:
        """Snapshot what the turn's artefacts need (on the loop) and return the writer (thread-safe,
        :func:`host.run.turn_files.turn_writer`: timeline.json and summary.json first, then the plots).

        ``plots``: draw timeline.png and joints.png (None: the session's :attr:`SessionOptions.plots`).
        ``plots=True`` on a session made without plots draws without the warm-up of :meth:`__aenter__` (no
        caller does: its first plot holds the GIL for a while). Without plots the joint history is not
        copied either (the whole run's samples, on the loop)."""
        if plots is None:
            plots = self.opts.plots
        runtime = self._runtime
        plot = (turn_plotter(turn.out, list(turn.calls), turn.board_t0, label, self.rec,
                             list(runtime.streamer.history) if runtime is not None else [], self.robot)
                if plots else None)
        return turn_writer(turn.out, list(turn.calls), turn.summary, turn.board_t0, self.out / "board.stderr", plot)

    def write_now(self, turn: TurnResult, label: str | None = None, *, plots: bool | None = None) -> None:
        """Write a turn's artefacts in this thread (e.g. after the session ended; ``plots=False``: no
        timeline.png / joints.png, for a process that must exit at once; None: the session's setting)."""
        self.writer(turn, label or turn.summary.task, plots=plots)()

    async def write(self, turn: TurnResult, label: str | None = None) -> None:
        """Write a turn's artefacts; the plotting runs in a worker thread so the board keeps its frames."""
        await anyio.to_thread.run_sync(self.writer(turn, label or turn.summary.task))


def _targets_at(history: Any) -> Callable[[int], Any]:
    """``targets(t_us)``: the targets of the last frame sent at or before board time ``t_us`` (None before
    the first; ``history`` is the streamer's bounded, time-ordered deque of ``(t_us, targets)``)."""

    def targets(t_us: int) -> Any:
        for i in range(len(history) - 1, max(-1, len(history) - 400), -1):  # recent frames: 4 s at 100 Hz
            t, q = history[i]
            if t <= t_us:
                return q
        return None

    return targets


async def _one(text: str) -> AsyncIterator[str]:
    yield text


def _cut_result(result: RunResult | None, t0: float, grace_s: float) -> RunResult:
    """The result of a turn the stop's deadline cancelled (``result``: the shell's run as far as it got):
    calls that had not ended are ``cancelled``, with an error naming the deadline."""
    if result is None:
        return RunResult(Timeline(), [], t0, interrupted=True)
    for r in result.timeline:
        if r.end is None and r.outcome not in ("done", "failed", "timeout", "cancelled", "interrupted"):
            r.outcome = "cancelled"  # type: ignore[assignment]
            r.error = r.error or (f"cut by the stop's {grace_s:g}-s deadline while "
                                  f"{'running' if r.start is not None else 'queued'}")
    result.interrupted = True
    return result


__all__ = ["RobotSession", "SessionOptions", "TurnResult"]
